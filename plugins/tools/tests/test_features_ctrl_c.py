"""Ctrl-C at a terminal (SIGINT to the whole process group) while ``features build`` starts or
runs its local Dask cluster: the command stops with the one line ``interrupted`` and 130. The
cluster's worker processes are in that group too; they are held deaf to it (their build stops
them), where each took it as its own KeyboardInterrupt, printed a traceback and died, and the
cluster failing to start was an internal error ("Nanny failed to start")."""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.config_sources import ENV_PREFIX

STORE = Path(__file__).resolve().parents[3] / "data" / "flights" / "naip_demo" / "tiles.mbtiles"
# 605 windows a task each: still extracting when stopped, however fast the machine
_MANY_WINDOWS = ("--window", "128", "--stride", "64", "--batch", "1")


def _running(group: int) -> list[bytes]:
    """The command lines of the processes of ``group`` still running (not zombies)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            state = (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
            if os.getpgid(int(entry.name)) == group and state != "Z":
                found.append((entry / "cmdline").read_bytes())
        except (OSError, IndexError):  # gone meanwhile
            continue
    return found


def _workers(group: int) -> int:
    """How many processes multiprocessing spawned (the Dask workers) run in ``group``."""
    return sum(b"multiprocessing.spawn" in cmdline for cmdline in _running(group))


def _wait(until: Callable[[], object], proc: subprocess.Popen[bytes] | None, what: str) -> None:
    deadline = time.monotonic() + 120
    while not until():
        assert proc is None or proc.poll() is None, f"the build ended before {what}"
        assert time.monotonic() < deadline, f"no {what} in 120 s"
        time.sleep(0.01)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("moment", "after_s"),
    [("starting", 0.0), ("starting", 0.4), ("running", 0.0)],
    ids=["first-worker-spawned", "workers-starting", "windows-extracting"],
)
def test_ctrl_c_to_the_process_group_is_one_line_and_130(
    tmp_path: Path, engine_dir: Path, moment: str, after_s: float
) -> None:
    store = tmp_path / "s.mbtiles"
    shutil.copyfile(STORE, store)
    err = tmp_path / "stderr"
    env = {k: v for k, v in os.environ.items() if not k.startswith(ENV_PREFIX)}
    env[f"{ENV_PREFIX}ENGINES__DIRECTORY"] = str(engine_dir)
    argv = [sys.executable, "-m", "c3_matcher.cli", "features", "build", str(store)]
    with err.open("wb") as sink:
        proc = subprocess.Popen(
            [*argv, "--strategy", "xfeat", "--workers", "2", *_MANY_WINDOWS],
            stdout=subprocess.DEVNULL,
            stderr=sink,
            env=env,
            cwd=tmp_path,
            start_new_session=True,  # a group of its own, as a terminal's foreground job
        )
        try:
            if moment == "starting":
                _wait(lambda: _workers(proc.pid) >= 1, proc, "worker process")
            else:
                _wait(lambda: b"windows/s" in err.read_bytes(), proc, "window extracted")
            time.sleep(after_s)
            os.killpg(proc.pid, signal.SIGINT)
            code = proc.wait(timeout=120)
            _wait(lambda: not _running(proc.pid), None, "end of its workers")  # none left behind
        finally:  # whatever failed, nothing of the group outlives the test
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    lines = err.read_text().splitlines()
    assert code == 130, lines
    if moment == "starting":  # stopped once started, before a window was planned
        assert lines == ["c3-matcher: interrupted"]
    else:  # its progress, then the one line (no worker's traceback or warning)
        assert lines[-1] == "c3-matcher: interrupted", lines
        assert all(line.startswith("features xfeat: ") for line in lines[:-1]), lines


def test_a_stop_this_process_ignores_stays_ignored(monkeypatch: pytest.MonkeyPatch) -> None:
    """A build started in the background, SIGINT ignored (``nohup``, ``&`` in a script)."""
    from c3_matcher_tools.features.cluster import stops_deferred

    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with stops_deferred():
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.1)
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    except KeyboardInterrupt:
        pytest.fail("an ignored SIGINT stopped the block")
    finally:
        signal.signal(signal.SIGINT, previous)


@pytest.mark.slow
def test_a_stop_taken_and_gone_on_from_still_ends_the_build_130_and_incomplete(
    small_flight: Callable[..., Path],
    engine_dir: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Ctrl-C that lands where a library takes the KeyboardInterrupt and goes on (as Dask's
    result gathering did: the build ran to its end and said 0, its map read as complete)."""
    import json

    from c3_matcher.cli import main
    from c3_matcher_tools.features import build

    flight = small_flight("stopped")
    monkeypatch.setenv(f"{ENV_PREFIX}ENGINES__DIRECTORY", str(engine_dir))
    real_task, calls = build.task, []

    def stopped_in_a_library(*args: Any) -> Any:
        calls.append(args)
        if len(calls) == 2:
            with contextlib.suppress(KeyboardInterrupt):  # taken there, and gone on from
                signal.raise_signal(signal.SIGINT)
        return real_task(*args)

    monkeypatch.setattr(build, "task", stopped_in_a_library)
    argv = ["features", "build", str(flight), "--strategy", "xfeat", "--workers", "0"]
    assert main([*argv, "--flight-candidates", "--batch", "1"]) == 130
    assert capsys.readouterr().err.splitlines()[-1] == "c3-matcher: interrupted"
    assert main(["features", "info", str(flight / "tiles.mbtiles"), "--json"]) == 0
    (found,) = json.loads(capsys.readouterr().out)["sets"]
    assert (found["complete"], found["windows"]) == (False, 1)  # stored before the stop, alone
