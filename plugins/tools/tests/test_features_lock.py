"""One ``features build`` of a store at a time: a second one, started while another process holds
the store's build lock, is refused at once in one line naming the store (exit 2) and writes
nothing; a killed build's lock stops nothing; the sidecar's readers never wait on the lock; and
the local Dask cluster takes no fixed port, so builds of different stores run side by side
without Dask's "Port 8787 is already in use" warning."""

from __future__ import annotations

import fcntl
import os
import signal
import socket
import subprocess
import sys
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

_HOLD = """
import fcntl, os, sys
fd = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT, 0o644)
fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
os.write(fd, f"{os.getpid()}\\n".encode())
print("held", flush=True)
sys.stdin.read()
"""


@contextmanager
def _held_by_another_process(lock: Path) -> Iterator[subprocess.Popen[str]]:
    """``lock`` held (``flock``) by a child process, as a running build holds it."""
    with subprocess.Popen(
        [sys.executable, "-c", _HOLD, str(lock)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    ) as child:
        try:
            assert child.stdout is not None and child.stdout.readline() == "held\n"
            yield child
        finally:
            child.kill()


def _lock_of(store: Path) -> Path:
    return store.with_name(store.name + ".features.sqlite.lock")


def _build(store: Path, *more: str) -> list[str]:
    return ["features", "build", str(store), "--strategy", "xfeat", "--workers", "0", *more]


@pytest.fixture()
def built_engines(engine_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The builds below run on the test session's engines."""
    monkeypatch.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(engine_dir))


@pytest.mark.usefixtures("built_engines")
def test_a_second_build_of_a_store_is_refused_at_once_naming_it(
    small_flight: Callable[..., Path], capsys: pytest.CaptureFixture[str]
) -> None:
    from c3_matcher.cli import main

    store = small_flight("busy") / "tiles.mbtiles"
    lock = _lock_of(store)
    with _held_by_another_process(lock) as other:
        assert main(_build(store)) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1, err
        assert f"{store}: another build of its features is running (process {other.pid})" in err
        assert "run this one again when it has finished" in err
        assert not store.with_name(store.name + ".features.sqlite").exists()  # nothing written
        fd = os.open(lock, os.O_RDWR)  # the holder's lock is left as it is: still held
        try:
            with pytest.raises(BlockingIOError):
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        finally:
            os.close(fd)


@pytest.mark.slow
@pytest.mark.usefixtures("built_engines")
def test_a_killed_builds_lock_stops_nothing_and_no_reader_waits_on_a_build(
    small_flight: Callable[..., Path], capsys: pytest.CaptureFixture[str]
) -> None:
    from c3_matcher.cli import main

    flight = small_flight("killed")
    store = flight / "tiles.mbtiles"
    lock = _lock_of(store)
    with _held_by_another_process(lock) as other:
        os.kill(other.pid, signal.SIGKILL)
        other.wait()
    assert lock.read_text() == f"{other.pid}\n"  # left by the killed build: stops nothing
    assert main(_build(flight, "--flight-candidates")) == 0
    assert not lock.exists()  # removed when the build ends
    capsys.readouterr()
    with _held_by_another_process(lock):  # a build running: readers go on as ever
        assert main(["features", "info", str(store), "--verify", "--json"]) == 0
        out = capsys.readouterr().out
        assert '"complete": true' in out and '"damaged": 0' in out
        other_store = small_flight("beside", where="other") / "tiles.mbtiles"
        assert main(_build(other_store, "--window", "512")) == 0  # another store: not held


def test_the_local_cluster_takes_no_fixed_port() -> None:
    from c3_matcher_tools.features.cluster import dask_client

    with socket.socket() as taken:  # 8787 held, as by another build's cluster
        try:
            taken.bind(("127.0.0.1", 8787))
            taken.listen()
        except OSError:
            pass  # something else holds it already
        with warnings.catch_warnings(record=True) as said:
            warnings.simplefilter("always")
            with dask_client(1, None) as client:
                http = client.cluster.scheduler.http_server
                assert client.submit(sum, [1, 2]).result() == 3
    assert not [w for w in said if "already in use" in str(w.message)], [
        str(w.message) for w in said
    ]
    assert http.port != 8787 and http.address == "127.0.0.1"  # a free port, this machine only
