"""Build an offline wheelhouse for build profiles: the core, the profile distribution, the
plugins it links (and the ground tools for ground profiles), every run-time dependency, and the
profile's engines, so an airborne computer with no network installs and starts from that folder
alone:

    .venv/bin/python scripts/wheelhouse.py airborne --out dist/wheelhouse-airborne \\
        --engines .engines
    # on the target, offline:
    python3 -m venv /opt/c3 && /opt/c3/bin/pip install --no-index \\
        --find-links dist/wheelhouse-airborne "c3-matcher[airborne]"
    C3_MATCHER_ENGINES__DIRECTORY=dist/wheelhouse-airborne/engines /opt/c3/bin/c3-matcher plugins

Engines are copied from ``--engines`` (none without it), after ``c3-matcher engines build`` in
this (build) environment; only those of the plugins the profile links are copied. Needs network
(PyPI) here, never on the target.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PIP = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]


def linked_plugin_dirs(profile: str) -> list[Path]:
    matrix = tomllib.loads((REPO / "buildflags" / "matrix.toml").read_text())
    row = matrix["profiles"][profile]
    dirs = [
        REPO / info["plugin_dir"] for flag, info in matrix["flags"].items() if row[flag] == "ON"
    ]
    if row.get("tools"):  # the ground tools: every profile but airborne
        dirs.append(REPO / matrix["tools"]["plugin_dir"])
    return [d for d in dirs if (d / "pyproject.toml").is_file()]


def _clean_copy(source: Path, target: Path) -> Path:
    """``source``'s project copied to ``target`` without what earlier builds left in it: each
    wheel is built in a folder of its own, so the checkout gets no ``build/`` or ``*.egg-info``
    and nothing else touches a build while it runs."""
    leftovers = shutil.ignore_patterns("build", "dist", "*.egg-info", "__pycache__", ".*_cache")
    shutil.copytree(source, target, ignore=leftovers)
    return target


def build(profiles: list[str], out: Path, engines: Path | None, extra: list[Path]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    sources = {REPO / "core"}
    for profile in profiles:
        sources |= {REPO / "buildflags" / profile, *linked_plugin_dirs(profile)}
    sources |= set(extra)
    print(f"wheelhouse: building {len(sources)} local wheels", file=sys.stderr)
    with tempfile.TemporaryDirectory(prefix="c3-wheelhouse-") as tmp:
        copies = [
            _clean_copy(source, Path(tmp) / f"{i:02d}") for i, source in enumerate(sorted(sources))
        ]
        subprocess.run([*PIP, "wheel", "--no-deps", "-w", str(out), *map(str, copies)], check=True)
    requirements = [f"c3-matcher[{p}]" for p in profiles]
    print("wheelhouse: downloading run-time dependencies", file=sys.stderr)
    subprocess.run(
        [
            *PIP,
            "download",
            "--only-binary=:all:",
            "--find-links",
            str(out),
            "-d",
            str(out),
            *requirements,
        ],
        check=True,
    )
    if engines is not None:
        copy_engines(profiles, out / "engines", engines)
    print(f"wheelhouse: {out} ({sum(1 for _ in out.glob('*.whl'))} wheels)", file=sys.stderr)


def copy_engines(profiles: list[str], target: Path, source: Path) -> None:
    """Copy the engines (and manifests) that the profiles' plugins declare, as the plugin host
    of each profile sees them in this (build) environment."""
    from c3_matcher.engines.naming import manifest_path_for
    from c3_matcher.engines.store import EngineStore
    from c3_matcher.plugins.manager import PluginHost, discover
    from c3_matcher.profiles import BuildProfile

    sys.path.insert(0, str(REPO / "buildflags"))
    from generate import load_matrix, profile_rows

    rows = profile_rows(load_matrix())
    store = EngineStore(source)
    target.mkdir(parents=True, exist_ok=True)
    for profile in profiles:
        host = PluginHost(BuildProfile.from_data(rows[profile], None), discover())
        for spec in host.engine_specs():
            path = store.require_spec(spec)  # the build of the graph the plugin runs
            for f in (path, manifest_path_for(path)):
                shutil.copy2(f, target / f.name)
                print(f"wheelhouse: engine {f.name}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("profiles", nargs="+", help="airborne, research, replay-cli, ...")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument(
        "--engines",
        type=Path,
        default=None,
        help="engine directory to copy from (omit: no engines)",
    )
    parser.add_argument(
        "--extra",
        type=Path,
        action="append",
        default=[],
        help="another local distribution to include (e.g. a plugin)",
    )
    args = parser.parse_args(argv)
    build(args.profiles, args.out, args.engines, args.extra)
    return 0


if __name__ == "__main__":
    sys.exit(main())
