"""Every build profile installed from built wheels into its own fresh virtual environment,
offline (pip --no-index inside a network namespace with no network when the machine allows it),
as a flight-software build would; then what `c3-matcher plugins` reports and what selecting each
strategy does must be what buildflags/matrix.toml says. The example third-party plugin is
installed beside research (loaded) and airborne (ignored).

The wheelhouse is built by scripts/wheelhouse.py (the documented offline-deployment command),
with the profile's engines; the target environments then never reach a package index."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tomllib
import venv
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PROFILES = ("airborne", "research", "replay-cli", "operator-tooling")
MATRIX = tomllib.loads((REPO / "buildflags" / "matrix.toml").read_text())
EXAMPLE = REPO / "tests" / "example_plugin"
DEMO = REPO / "data" / "demo"
# one test process builds the wheelhouse (about 80 s) and runs every install (scripts/test runs
# the tests in two processes: --dist loadgroup)
pytestmark = pytest.mark.xdist_group("install")


def offline(cmd: list[str]) -> list[str]:
    """Run ``cmd`` with the network out of reach (a fresh network namespace) when possible."""
    unshare = shutil.which("unshare")
    if unshare and subprocess.run([unshare, "-n", "true"], capture_output=True).returncode == 0:
        return [unshare, "-n", *cmd]
    return cmd


@pytest.fixture(scope="module")
def wheelhouse(engine_dir, tmp_path_factory) -> Path:  # type: ignore[no-untyped-def]
    out = tmp_path_factory.mktemp("wheelhouse")
    subprocess.run(
        [
            sys.executable,
            str(REPO / "scripts" / "wheelhouse.py"),
            *PROFILES,
            "--out",
            str(out),
            "--engines",
            str(engine_dir),
            "--extra",
            str(EXAMPLE),
        ],
        check=True,
    )
    return out


class Env:
    def __init__(self, root: Path, wheelhouse: Path) -> None:
        self.root = root
        self.wheelhouse = wheelhouse
        venv.EnvBuilder(with_pip=True).create(root)

    def pip_install(self, *requirements: str) -> None:
        cmd = [
            str(self.root / "bin" / "python"),
            "-m",
            "pip",
            "install",
            "-q",
            "--disable-pip-version-check",
            "--no-index",
            "--find-links",
            str(self.wheelhouse),
            *requirements,
        ]
        env = {k: v for k, v in os.environ.items() if not k.startswith("PIP_")}
        subprocess.run(offline(cmd), check=True, env={**env, "PIP_CONFIG_FILE": os.devnull})

    def packages(self) -> set[str]:
        listing = subprocess.run(
            [str(self.root / "bin" / "python"), "-m", "pip", "list", "--format=json"],
            capture_output=True,
            text=True,
            check=True,
        )
        return {p["name"].lower().replace("_", "-") for p in json.loads(listing.stdout)}

    def size_mib(self) -> float:
        return sum(f.stat().st_size for f in self.root.rglob("*") if f.is_file()) / 2**20

    def c3(self, *args: str, **env_extra: str) -> subprocess.CompletedProcess[str]:
        env = {k: v for k, v in os.environ.items() if not k.startswith("C3_MATCHER_")}
        env.update(
            {
                "C3_MATCHER_ENGINES__DIRECTORY": str(self.wheelhouse / "engines"),
                "C3_MATCHER_FDR__PATH": str(self.root / "fdr.jsonl"),
                # a small budget keeps LightGlue fast; XFeat's mutual-NN needs its own 4096
                "C3_MATCHER_MATCHER__MAX_KEYPOINTS": "512",
                "C3_MATCHER_MATCHER__OPTIONS__XFEAT__MAX_KEYPOINTS": "4096",
                **env_extra,
            }
        )
        return subprocess.run(
            offline([str(self.root / "bin" / "c3-matcher"), *args]),
            capture_output=True,
            text=True,
            env=env,
            cwd=self.root,
            timeout=900,
        )


def _commands(help_text: str) -> list[str]:
    """The subcommand names of an argparse help text (its first ``{a,b,...}`` group)."""
    start = help_text.index("{") + 1
    return help_text[start : help_text.index("}", start)].split(",")


def demo_match(env: Env, strategy: str, *extra: str) -> subprocess.CompletedProcess[str]:
    meta = json.loads((DEMO / "demo.json").read_text())
    att = meta["attitude_deg"]
    args = [
        *extra,
        "match",
        "--strategy",
        strategy,
        "--query",
        str(DEMO / "frame.jpg"),
        "--calibration",
        str(DEMO / "calibration.json"),
        "--attitude",
        f"{att['roll']},{att['pitch']},{att['yaw']}",
        "--height",
        str(meta["height_m"]),
        "--tile-gsd",
        str(meta["tile_gsd_m"]),
        "--no-correspondences",
    ]
    for t in meta["tiles"]:
        args += ["--tile", str(DEMO / t["file"])]
    return env.c3(*args)


def expected(profile: str) -> dict[str, str]:
    return {
        info["strategy"]: MATRIX["profiles"][profile][flag]
        for flag, info in MATRIX["flags"].items()
    }


@pytest.mark.slow
@pytest.mark.parametrize("profile", PROFILES)
def test_profile_installs_offline_and_behaves_as_the_matrix_says(profile, wheelhouse, tmp_path):
    env = Env(tmp_path / "venv", wheelhouse)
    env.pip_install(f"c3-matcher[{profile}]")
    probe = subprocess.run(
        [str(env.root / "bin" / "python"), "-c", "import torch"], capture_output=True
    )
    assert probe.returncode != 0, "the run-time install must not contain torch"
    report = json.loads(env.c3("plugins", "--json").stdout)
    states = expected(profile)
    assert report["profile"] == profile
    flags = {flag: MATRIX["profiles"][profile][flag] for flag in MATRIX["flags"]}
    assert report["flags"] == flags
    linked = {s for s, state in states.items() if state == "ON"}
    tools = bool(MATRIX["profiles"][profile]["tools"])
    baselines = {"sift_magsac"} if tools else set()  # the ground tools' hooked baseline
    assert {s["name"] for s in report["strategies"]} == linked | baselines
    assert report["errors"] == []
    check = subprocess.run(
        [str(env.root / "bin" / "python"), "-m", "pip", "check"], capture_output=True, text=True
    )
    assert check.returncode == 0, check.stdout + check.stderr
    installed = env.packages()
    print(f"{profile}: {env.size_mib():.0f} MiB, packages: {', '.join(sorted(installed))}")
    assert ("c3-matcher-tools" in installed) == tools
    assert ("tifffile" in installed) == tools  # a ground dependency only
    commands = set(_commands(env.c3("--help").stdout))
    flight = {"plugins", "config", "engines", "match", "fdr"}
    ground = {"tiles", "dataset", "replay", "eval", "bench", "features"}
    assert commands == (flight | ground if tools else flight)
    engines = set(_commands(env.c3("engines", "--help").stdout))
    assert engines == ({"list", "verify", "build", "bench"} if tools else {"list", "verify"})
    for strategy, state in states.items():
        proc = demo_match(env, strategy)
        if state == "ON":
            assert proc.returncode == 0, proc.stderr[-3000:]
            result = json.loads(proc.stdout)
            assert result["matcher_label"] == strategy
            assert result["per_candidate"][0]["tile_index"] == 1  # the demo's true tile
        else:
            assert proc.returncode == 2, proc.stderr[-3000:]
            assert "not linked" in proc.stderr and profile in proc.stderr
            assert "BUILD_MATCHER_" in proc.stderr
    config = env.c3("config", "--json")
    assert config.returncode == 0 and json.loads(config.stdout)["matcher"]["strategy"]
    log = env.c3("fdr", "--json")  # the log every match above wrote, checked where it flies
    assert log.returncode == 0, log.stdout + log.stderr
    frames = json.loads(log.stdout)["kinds"].get("matcher.frame_done", 0)
    assert frames == list(states.values()).count("ON")


@pytest.mark.slow
def test_third_party_plugin_is_discovered_selected_and_run(wheelhouse, tmp_path):
    research = Env(tmp_path / "research", wheelhouse)
    research.pip_install("c3-matcher[research]", "c3-matcher-example-fast-disk")
    report = json.loads(research.c3("plugins", "--json").stdout)
    names = {s["name"]: s for s in report["strategies"]}
    assert names["example_fast_disk"]["distribution"] == "c3-matcher-example-fast-disk"
    toml = tmp_path / "flight.toml"
    toml.write_text(
        '[matcher]\nstrategy = "example_fast_disk"\n'
        "[matcher.options.example_fast_disk]\nmax_keypoints = 256\n"
    )
    proc = demo_match(research, "example_fast_disk", "--config", str(toml))
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert json.loads(proc.stdout)["matcher_label"] == "example_fast_disk"
    toml.write_text(
        '[matcher]\nstrategy = "example_fast_disk"\n'
        "[matcher.options.example_fast_disk]\nmax_keypoint = 256\n"
    )
    bad = demo_match(research, "example_fast_disk", "--config", str(toml))
    assert bad.returncode == 2 and "max_keypoint" in bad.stderr

    airborne = Env(tmp_path / "airborne", wheelhouse)
    airborne.pip_install("c3-matcher[airborne]", "c3-matcher-example-fast-disk")
    report = json.loads(airborne.c3("plugins", "--json").stdout)
    assert "example_fast_disk" not in {s["name"] for s in report["strategies"]}
    assert [p["distribution"] for p in report["ignored"]] == ["c3-matcher-example-fast-disk"]
    refused = demo_match(airborne, "example_fast_disk")
    assert refused.returncode == 2 and "not linked" in refused.stderr


@pytest.mark.slow
def test_two_profiles_in_one_environment_are_refused(wheelhouse, tmp_path):
    env = Env(tmp_path / "venv", wheelhouse)
    env.pip_install("c3-matcher[airborne]", "c3-matcher-profile-research")
    proc = env.c3("plugins")
    assert proc.returncode == 1 and "more than one build profile" in proc.stderr
