"""``engines build`` into an engine directory that cannot hold the engine (a file-size limit, as a
full disk): the failure names the file that could not be written, in that directory, and no
engine or scratch folder is left."""

from __future__ import annotations

from pathlib import Path

import pytest

from c3_matcher_tools.testing.cli import run_cli


@pytest.mark.slow
def test_an_engine_past_the_file_size_limit_names_the_file_it_was_writing(tmp_path: Path) -> None:
    engines = tmp_path / "engines"
    r = run_cli(
        "engines",
        "build",
        "--only",
        "xfeat/default",
        cwd=tmp_path,
        engine_dir=engines,
        timeout=600,
        limit_file_bytes=1 << 20,  # the XFeat graph is about 6 MB
    )
    assert r.returncode == 1, r.stderr
    last = r.stderr.strip().splitlines()[-1]
    assert "engine build xfeat/default failed: export failed: OSError: [Errno 27]" in last, last
    assert f"File too large: '{engines}/.build-xfeat_default_" in last, last
    assert last.endswith(".onnx'; no engine was kept"), last
    assert list(engines.iterdir()) == []
