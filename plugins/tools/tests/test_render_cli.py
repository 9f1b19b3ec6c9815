"""``tiles build`` (default zoom) then ``dataset render`` with its defaults; render checks its
inputs before writing, writes atomically and leaves nothing behind on failure."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import pytest

from c3_matcher_tools.testing.cli import run_cli

REPO = Path(__file__).resolve().parents[3]
NAIP = REPO / "data" / "imagery" / "naip_timeseries"
NAIP_2020 = NAIP / "m_4709963_se_14_1_20200831.tif"
NAIP_2010 = NAIP / "m_4709963_se_14_1_20100629.tif"
ELSEWHERE = REPO / "data" / "imagery" / "open_orthophotos" / "test_tiled.tif"


def _cli(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return run_cli(*args, cwd=REPO, timeout=300)


def _render_options() -> set[str]:
    out = _cli("dataset", "render", "--help").stdout
    return set(re.findall(r"--[a-z][a-z-]+", out))


def _leftovers(parent: Path, name: str) -> list[str]:
    return sorted(p.name for p in parent.iterdir() if name in p.name)


def test_default_zoom_store_renders_with_defaults(tmp_path: Path) -> None:
    store = tmp_path / "x.mbtiles"
    built = _cli("tiles", "build", NAIP_2020, store, "--json")
    assert built.returncode == 0, built.stderr
    assert json.loads(built.stdout)["zoom"] == 15  # 3.26 m/px, not coarser than the 5 m source
    out = tmp_path / "ds"
    r = _cli("dataset", "render", NAIP_2010, store, out, "--frames", "6", "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["frames"] == 6
    assert sorted(p.name for p in out.iterdir()) == [
        "calibration.json",
        "dataset.json",
        "frames",
        "frames.jsonl",
        "tiles.mbtiles",
    ]
    assert len(list((out / "frames").iterdir())) == 6
    assert _leftovers(tmp_path, ".ds.") == []
    # an existing OUT is refused and left as it was; --force replaces it
    before = (out / "frames.jsonl").read_bytes()
    again = _cli("dataset", "render", NAIP_2010, store, out, "--frames", "3")
    assert again.returncode == 2 and "--force" in again.stderr
    assert (out / "frames.jsonl").read_bytes() == before
    forced = _cli("dataset", "render", NAIP_2010, store, out, "--frames", "3", "--force")
    assert forced.returncode == 0, forced.stderr
    assert len((out / "frames.jsonl").read_text().splitlines()) == 3
    assert _leftovers(tmp_path, ".ds.") == []


def test_failed_render_leaves_nothing_and_names_real_options(tmp_path: Path) -> None:
    store = tmp_path / "z14.mbtiles"
    assert _cli("tiles", "build", NAIP_2020, store, "--zoom", "14").returncode == 0
    out = tmp_path / "ds"
    r = _cli("dataset", "render", NAIP_2010, store, out)
    assert r.returncode == 2
    assert not out.exists() and _leftovers(tmp_path, "ds") == []
    named = set(re.findall(r"--[a-z][a-z-]+", r.stderr)) - {"--zoom"}
    assert named, r.stderr
    assert named <= _render_options(), (named, r.stderr)
    assert "tiles build --zoom 15" in r.stderr


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (("missing.tif", "STORE"), "FRAMES_GEOTIFF"),
        ((NAIP_2010, "missing.mbtiles"), "STORE"),
        ((NAIP_2010, NAIP_2010), "STORE"),
        ((NAIP_2010, "elsewhere.mbtiles"), "do not overlap"),  # Dakota frames, a Dutch store
    ],
)
def test_render_checks_inputs_before_writing(
    tmp_path: Path, args: tuple[str | Path, str | Path], needle: str
) -> None:
    resolved = [tmp_path / a if isinstance(a, str) else a for a in args]
    if args[1] == "elsewhere.mbtiles":
        assert _cli("tiles", "build", ELSEWHERE, resolved[1]).returncode == 0
    out = tmp_path / "ds"
    r = _cli("dataset", "render", *resolved, out)
    assert r.returncode == 2 and needle in r.stderr, r.stderr
    assert not out.exists() and _leftovers(tmp_path, "ds") == []


def test_trajectory_off_the_imagery_names_cli_options(tmp_path: Path) -> None:
    store = tmp_path / "x.mbtiles"
    assert _cli("tiles", "build", NAIP_2020, store).returncode == 0
    out = tmp_path / "ds"
    r = _cli("dataset", "render", NAIP_2010, store, out, "--radius", "3000", "--frames", "4")
    assert r.returncode == 2 and "--radius" in r.stderr, r.stderr
    assert set(re.findall(r"--[a-z][a-z-]+", r.stderr)) <= _render_options()
    assert not out.exists() and _leftovers(tmp_path, "ds") == []
