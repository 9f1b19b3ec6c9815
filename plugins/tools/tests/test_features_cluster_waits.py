"""``features build`` on Dask ends in one line when the cluster cannot run it: an existing
cluster with no worker (all died, or none connected) held the build for ever, saying nothing,
and workers that kept dying while running a task ended in "internal error: KilledWorker". Each
is exit 1 (a failure, not bad input), naming the cluster. The command line, in a subprocess."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

STORE = Path(__file__).resolve().parents[3] / "data" / "flights" / "naip_demo" / "tiles.mbtiles"
WORKERLESS_S = 3.0  # the bound the test builds with (a build's own: a minute)


def _run(
    script: str, store: Path, engine_dir: Path, **env: str
) -> subprocess.CompletedProcess[str]:
    """``script`` (Python, given the store path as ``STORE``) in a subprocess, within 240 s."""
    environment = {k: v for k, v in os.environ.items() if not k.startswith("C3_MATCHER_")}
    environment.update(C3_MATCHER_ENGINES__DIRECTORY=str(engine_dir), **env)
    code = f"STORE = {str(store)!r}\n" + textwrap.dedent(script)
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=environment,
        cwd=store.parent, timeout=240,
    )  # fmt: skip


@pytest.fixture()
def store(tmp_path: Path) -> Path:
    path = tmp_path / "tiles.mbtiles"
    shutil.copy(STORE, path)
    return path


def test_a_cluster_without_a_worker_ends_the_build_naming_it(store: Path, engine_dir: Path) -> None:
    script = f"""
        import functools, sys
        from dask.distributed import LocalCluster
        from c3_matcher.cli import main
        from c3_matcher_tools.features import build

        build.build_features = functools.partial(build.build_features, workerless_s={WORKERLESS_S})
        with LocalCluster(n_workers=0, processes=False, dashboard_address=None) as cluster:
            print(cluster.scheduler_address, flush=True)
            args = ["features", "build", STORE, "--strategy", "xfeat"]
            sys.exit(main([*args, "--scheduler", cluster.scheduler_address]))
    """
    started = time.monotonic()
    proc = _run(script, store, engine_dir)
    took = time.monotonic() - started
    address = proc.stdout.split()[0]
    assert proc.returncode == 1, proc.stderr
    said = [line for line in proc.stderr.splitlines() if line.startswith("c3-matcher:")]
    assert said == [
        f"c3-matcher: features build: the Dask cluster at {address} has had no worker for "
        f"{WORKERLESS_S:g} s (its workers died, or none connected): stopped; the windows done "
        "are kept, and a build again goes on from them"
    ], proc.stderr
    assert took < 120, f"{took:.0f} s"


def test_workers_that_keep_dying_end_the_build_in_one_line(store: Path, engine_dir: Path) -> None:
    script = """
        import os, sys
        from c3_matcher.cli import main
        from c3_matcher_tools.features import build

        def dying(*args, **kwargs):  # the worker process running it dies, as one out of memory
            os._exit(1)

        build.set_facts_task = dying
        sys.exit(main(["features", "build", STORE, "--strategy", "xfeat", "--workers", "1"]))
    """
    proc = _run(script, store, engine_dir, DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES="1")
    assert proc.returncode == 1, proc.stderr
    assert "internal error" not in proc.stderr
    said = [line for line in proc.stderr.splitlines() if line.startswith("c3-matcher:")]
    assert said == [
        "c3-matcher: features build: the workers of the local Dask cluster died running a "
        "task, one after another (out of memory? killed?): stopped; the windows done are "
        "kept, and a build again goes on from them"
    ], proc.stderr
