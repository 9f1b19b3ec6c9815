"""``features info`` over a sidecar in SQLite's WAL journal mode (older versions left their
sidecars so) and over one it cannot open: on read-only media the WAL sidecar is read as it is;
where its ``-shm`` cannot be made (and a writer may come) the command says so, and that
``features build`` on a writable copy makes it one file, instead of "unable to open database
file" treated as a permission problem; every refusal is whole sentences, one line, exit 2.

Read-only media: the file system's read-only flag, the condition the reader checks
(``files.on_read_only_media``), set for the test's folder; that no ``-shm`` can be made there is
real, for root too: the sidecar's name is as long as a name may be (see
core/tests/test_sidecar_read_only_media.py)."""

from __future__ import annotations

import json
import os
import shutil
import sqlite3
from collections.abc import Callable
from pathlib import Path

import pytest

from c3_matcher.testing.locks import exclusive_lock
from c3_matcher.testing.permissions import refuse_reading
from c3_matcher.tilestore import files
from c3_matcher.tilestore.features import FeatureSet, MapFeatureStore, sidecar_path

REPO = Path(__file__).resolve().parents[3]
STORE = REPO / "data" / "flights" / "naip_demo" / "tiles.mbtiles"
FSET = FeatureSet(
    "ab" * 32, "ab" * 32, "CPUExecutionProvider", 32, "none", 4, 256, 256, 64, "xfeat"
)


def _run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    from c3_matcher.cli import main

    capsys.readouterr()
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err.strip()


@pytest.fixture
def wal_store(tmp_path: Path) -> Path:
    """A copy of the demo store whose sidecar (holding FSET) is in WAL mode, as an older
    version left it, and whose name is as long as a name may be: no ``-shm`` can be made."""
    folder = tmp_path / "media"
    folder.mkdir()
    short = folder / "tiles.mbtiles"
    shutil.copy(STORE, short)
    with MapFeatureStore(sidecar_path(short), writable=True) as side:
        side.ensure_set(FSET)
        side.mark(FSET.set_id, complete=True, windows=0)
    db = sqlite3.connect(sidecar_path(short))
    assert db.execute("PRAGMA journal_mode=WAL").fetchone() == ("wal",)
    db.close()
    most = os.pathconf(folder, "PC_NAME_MAX") - len(".features.sqlite")
    store = folder / ("m" * (most - len(".mbtiles")) + ".mbtiles")
    sidecar_path(short).rename(sidecar_path(store))
    short.rename(store)
    assert sidecar_path(store).read_bytes()[18:20] == b"\x02\x02"
    return store


def test_features_info_reads_a_wal_sidecar_on_read_only_media(
    wal_store: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    inside = wal_store.parent.resolve()
    monkeypatch.setattr(files, "on_read_only_media", lambda p: inside in Path(p).parents)
    before = sorted(p.name for p in wal_store.parent.iterdir())
    code, out, err = _run(capsys, "features", "info", str(wal_store), "--json")
    assert code == 0, err
    assert [s["set_id"] for s in json.loads(out)["sets"]] == [FSET.set_id]
    assert "cannot be read" not in err and "unable to open" not in err
    assert sorted(p.name for p in wal_store.parent.iterdir()) == before


@pytest.mark.parametrize("verify", [(), ("--verify",)], ids=["info", "verify"])
def test_features_info_of_a_wal_sidecar_it_cannot_read_says_why_and_how_to_fix_it(
    verify: tuple[str, ...], wal_store: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    side = sidecar_path(wal_store)
    code, out, err = _run(capsys, "features", "info", str(wal_store), *verify)
    assert (code, out) == (2, ""), err
    assert len(err.splitlines()) == 1, err
    assert err.startswith(f"c3-matcher: {side}: cannot be read here: "), err
    assert f"WAL journal mode, which needs a {side.name}-shm file beside it" in err
    assert "the flight extracts every candidate instead while it is so. " in err
    assert err.endswith(f"keeping its features (then copy it back): {_build(wal_store)}."), err
    assert "unable to open database file" not in err and "permission" not in err


def test_features_info_of_a_locked_sidecar_says_so_in_whole_sentences(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    store = tmp_path / "tiles.mbtiles"
    shutil.copy(STORE, store)
    MapFeatureStore(sidecar_path(store), writable=True).close()
    with exclusive_lock(sidecar_path(store)):
        code, _, err = _run(capsys, "features", "info", str(store))
    assert code == 2 and len(err.splitlines()) == 1, err
    assert err.startswith(f"c3-matcher: {sidecar_path(store)}: locked by another process ("), err
    assert err.endswith(
        "; the flight extracts every candidate instead while it is so. Try again when it is "
        "released."
    ), err


def test_features_info_of_a_sidecar_it_may_not_read_says_what_to_do(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    store = tmp_path / "tiles.mbtiles"
    shutil.copy(STORE, store)
    MapFeatureStore(sidecar_path(store), writable=True).close()
    refuse_reading(monkeypatch, sidecar_path(store))
    code, _, err = _run(capsys, "features", "info", str(store))
    assert code == 2 and len(err.splitlines()) == 1, err
    assert err == (
        f"c3-matcher: {sidecar_path(store)}: cannot open (permission denied); the flight "
        "extracts every candidate instead while it is so. Let the user who runs c3-matcher "
        "read it and search its folder."
    )


def _build(store: Path) -> str:
    return f"c3-matcher features build {store}"


@pytest.mark.parametrize("verify", [(), ("--verify",)], ids=["info", "verify"])
@pytest.mark.parametrize(
    ("make", "what"),
    [(Path.mkdir, "a directory"), (os.mkfifo, "a special file (a pipe, socket or device)")],
    ids=["directory", "pipe"],
)
def test_features_info_json_of_a_directory_in_the_sidecars_place_is_a_document(
    make: Callable[[Path], None],
    what: str,
    verify: tuple[str, ...],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A script parsing ``--json`` gets the document an unreadable sidecar gets (same keys, no
    sets, the problem naming what is there instead), exit 2 and the one line on stderr: it got
    that line alone and nothing to parse."""
    unreadable = tmp_path / "unreadable" / "tiles.mbtiles"
    unreadable.parent.mkdir()
    shutil.copy(STORE, unreadable)
    MapFeatureStore(sidecar_path(unreadable), writable=True).close()
    refuse_reading(monkeypatch, sidecar_path(unreadable))
    _, other, _ = _run(capsys, "features", "info", str(unreadable), "--json")
    store = tmp_path / "tiles.mbtiles"
    shutil.copy(STORE, store)
    make(sidecar_path(store))
    code, out, err = _run(capsys, "features", "info", str(store), "--json", *verify)
    assert code == 2 and len(err.splitlines()) == 1, err
    document = json.loads(out)
    assert (
        list(document)
        == list(json.loads(other))
        == [
            "store",
            "sidecar",
            "sets",
            "problem",
            "command",
        ]
    )
    assert document["sidecar"] == str(sidecar_path(store)) and document["sets"] is None
    assert document["problem"] == (
        f"{sidecar_path(store)}: {what}, not a features sidecar; the flight ignores it and "
        "extracts every candidate instead. Move it away; features build then makes the "
        "sidecar there."
    )
    assert document["command"] is None and err == f"c3-matcher: {document['problem']}"
