"""A name stdout's encoding cannot hold (a directory's byte that is no UTF-8, a CJK name under
an ASCII or Latin-1 locale) costs no command its result: it is printed as Python's escape
(``\\udce9``), what Python's own stderr does, and the files are all written; ``--json`` stays
JSON. A chart titled in CJK draws the font's box without matplotlib's warning on stderr."""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import pytest

from c3_matcher_tools.report import charts

from .conftest import C3, DEMO, SmallFlight

_STRICT_ASCII = "ascii:strict"


@pytest.fixture(autouse=True)
def _ascii_stdout(monkeypatch: pytest.MonkeyPatch) -> None:
    """The commands' stdout can encode ASCII only, and fails on anything else."""
    monkeypatch.setenv("PYTHONIOENCODING", _STRICT_ASCII)


@pytest.mark.parametrize("as_json", [False, True])
def test_a_replay_named_in_bytes_stdout_cannot_encode_writes_its_run(
    tmp_path: Path, small_flight: SmallFlight, c3: C3, as_json: bool
) -> None:
    flight = small_flight("東京 flight", where="vol\udce9")
    out = tmp_path / "rep\udce9"
    done = c3("replay", flight, "--strategy", "sift_magsac", "--out", out, *["--json"] * as_json)
    assert done.returncode == 0, done.stderr
    for name in ("results.jsonl", "report.json", "flight.geojson", "report.html"):
        assert (out / name).is_file(), name
    if as_json:
        assert json.loads(done.stdout)["frames_done"] == 2
    else:
        assert "rep\\udce9/results.jsonl" in done.stdout, done.stdout
    assert "Glyph" not in done.stderr, done.stderr


def test_an_import_skipping_an_image_named_in_bytes_prints_its_name_escaped(
    tmp_path: Path, c3: C3
) -> None:
    images = tmp_path / "images"
    images.mkdir()
    frame = json.loads((DEMO / "frames.jsonl").read_text().splitlines()[0])
    shutil.copyfile(DEMO / frame["image"], images / "a.jpg")
    shutil.copyfile(DEMO / frame["image"], images / "\udcff.jpg")  # no telemetry row names it
    pose, (roll, pitch, yaw) = frame["pose"], frame["attitude_deg"]
    (tmp_path / "t.csv").write_text(
        "time_s,image,lat,lon,altitude_m,roll_deg,pitch_deg,yaw_deg\n"
        f"0,a.jpg,{pose['nadir_lat']},{pose['nadir_lon']},{frame['height_m']},"
        f"{roll},{pitch},{yaw}\n"
    )
    calibration, store = DEMO / "calibration.json", DEMO / "tiles.mbtiles"
    done = c3("dataset", "import", images, tmp_path / "t.csv", calibration, store, "ds")
    assert done.returncode == 0, done.stderr
    assert "\\udcff.jpg: no telemetry row" in done.stdout, done.stdout
    assert (tmp_path / "ds" / "dataset.json").is_file()


def test_dataset_info_of_a_frames_source_named_in_bytes_prints_it_escaped(
    small_flight: SmallFlight, c3: C3
) -> None:
    flight = small_flight("flight")
    meta = json.loads((flight / "dataset.json").read_text())
    meta["frames_source"] = "imported: tel\udce9.csv"
    (flight / "dataset.json").write_text(json.dumps(meta))
    done = c3("dataset", "info", flight)
    assert done.returncode == 0, done.stderr
    assert "frames_source: imported: tel\\udce9.csv" in done.stdout, done.stdout
    done = c3("dataset", "info", flight, "--json")
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["frames_source"] == "imported: tel\udce9.csv"


def test_a_chart_titled_in_cjk_warns_nothing() -> None:
    plt = charts._plt()
    fig, ax = plt.subplots()
    ax.set_title("東京 flight")
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        uri = charts._png_uri(fig)
    assert uri.startswith("data:image/png;base64,")
    assert [str(w.message) for w in said if "Glyph" in str(w.message)] == []
