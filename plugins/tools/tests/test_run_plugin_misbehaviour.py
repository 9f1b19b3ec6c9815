"""A run keeps its output when its strategy's backend misbehaves after start-up: a
``provenance()`` that raises loses no frame and no report (each frame's record and the run's
provenance say ``provenance_error``), and its own ``BaseException`` from ``extract`` on a frame is
that frame's backbone error, the run going on, and so is its own ``sys.exit()`` under ``replay``;
the host's own ``sys.exit`` (its SIGTERM handler's) while a frame is matched is no plugin's
failure: it reaches the host, the frame recorded first.
Real path: the shipped demo flight cut to two frames, the ``sift_magsac`` baseline composed as
``replay`` composes it, its FDR on disk."""

from __future__ import annotations

import json
import signal
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.cli import main
from c3_matcher.compose import build_plugin_host
from c3_matcher.config import C3Settings
from c3_matcher.pipeline import PipelineMatcher
from c3_matcher_tools.baselines import SiftBackend
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.run.flight import fly_prepared
from c3_matcher_tools.run.matcher import prepare_matcher
from c3_matcher_tools.run.records import FlightRun, FrameStatus
from c3_matcher_tools.run.run_mark import RUN_MARK

SmallFlight = Callable[..., Path]  # the fixture of conftest.py


class Abort(BaseException):
    """A plugin's own ``BaseException``."""


def _fly(
    flight: Path,
    out: Path,
    misbehave: Callable[[Any], None],
    flown: list[PipelineMatcher] | None = None,
) -> FlightRun:
    """The flight replayed with ``sift_magsac``, its backend made to ``misbehave`` once
    composed; the matcher appended to ``flown``."""
    host = build_plugin_host()
    with prepare_matcher(C3Settings(), "sift_magsac", plugin_host=host) as prepared:
        assert isinstance(prepared.matcher, PipelineMatcher)
        if flown is not None:
            flown.append(prepared.matcher)
        misbehave(prepared.matcher.backend)
        return fly_prepared(prepared, load_dataset(flight), out, plugin_host=host)


def _failing_once(raise_it: Callable[[], None]) -> Callable[[Any], None]:
    """The misbehaviour: the backend's first ``extract`` (the first frame's query) calls
    ``raise_it`` instead of extracting."""

    def misbehave(backend: Any) -> None:
        real = backend.extract
        calls: list[int] = []

        def extract(image: Any) -> Any:
            calls.append(1)
            if len(calls) == 1:
                raise_it()
            return real(image)

        backend.extract = extract

    return misbehave


def _frame_records(out: Path) -> list[dict[str, Any]]:
    lines = (out / "fdr.jsonl").read_text().splitlines()
    records = [json.loads(line) for line in lines]
    return [r for r in records if r["kind"].startswith("matcher.")]


def test_a_provenance_that_raises_loses_no_frame_and_no_run_output(
    small_flight: SmallFlight, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def unavailable() -> Any:
        raise RuntimeError("provenance unavailable")

    said = "provenance() raised RuntimeError: provenance unavailable"
    run = _fly(
        small_flight("prov"),
        tmp_path / "out",
        lambda backend: monkeypatch.setattr(backend, "provenance", unavailable),
    )
    assert run.provenance["provenance_error"] == said and "provider" not in run.provenance
    assert [o.status for o in run.outcomes] == [FrameStatus.OK, FrameStatus.INSUFFICIENT]
    records = _frame_records(tmp_path / "out")  # the second frame has no fix whatever it does
    assert [r["kind"] for r in records] == ["matcher.frame_done", "matcher.insufficient_inliers"]
    assert [r["payload"]["provenance_error"] for r in records] == [said, said]
    assert records[0]["payload"]["best_inlier_count"] >= 60


def test_a_plugins_own_base_exception_from_extract_is_that_frames_backbone_error(
    small_flight: SmallFlight, tmp_path: Path
) -> None:
    def gives_up() -> None:
        raise Abort("backend gave up")

    run = _fly(small_flight("abort"), tmp_path / "out", _failing_once(gives_up))
    statuses = [o.status for o in run.outcomes]
    assert statuses == [FrameStatus.BACKBONE_ERROR, FrameStatus.INSUFFICIENT]
    kinds = [(r["kind"], r["payload"].get("phase")) for r in _frame_records(tmp_path / "out")]
    assert kinds == [
        ("matcher.backbone_error", "query_extract"),
        ("matcher.insufficient_inliers", None),
    ]
    assert run.provenance["provider"]  # the backend's own, read at the end


def _replay_failing_once(
    raise_it: Callable[[], None], out: Path, flight: Path, monkeypatch: pytest.MonkeyPatch
) -> int:
    """``c3-matcher replay`` of ``flight`` with ``sift_magsac``, its backend's first ``extract``
    of a frame's query (the start-up probe's image has no calibration) calling ``raise_it``:
    the command's exit status."""
    real = SiftBackend.extract
    queries: list[int] = []

    def extract(self: SiftBackend, image: Any) -> Any:
        if image.calibration is not None:
            queries.append(1)
            if len(queries) == 1:
                raise_it()
        return real(self, image)

    with monkeypatch.context() as patched:
        patched.setattr(SiftBackend, "extract", extract)
        return main(["replay", str(flight), "--strategy", "sift_magsac", "--out", str(out)])


def test_a_plugins_own_sys_exit_in_extract_is_that_frames_backbone_error_and_replay_goes_on(
    small_flight: SmallFlight, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Under the command line a ``SystemExit`` during a frame is no signal handler's (SIGTERM
    is a ``KeyboardInterrupt`` there): a plugin's own ``sys.exit()`` fails only that frame, as
    any exception of its does; the replay scores both frames and ends, exit status and all, as
    with any frame's backbone error."""
    flight = small_flight("plugin_exit")

    def gives_up() -> None:
        raise RuntimeError("backend gave up")

    def quits() -> None:
        sys.exit(3)

    ended = {
        name: _replay_failing_once(raise_it, tmp_path / name, flight, monkeypatch)
        for name, raise_it in (("error", gives_up), ("exit", quits))
    }
    assert ended["exit"] == ended["error"]
    out = tmp_path / "exit"
    kinds = [(r["kind"], r["payload"].get("phase")) for r in _frame_records(out)]
    assert kinds == [
        ("matcher.backbone_error", "query_extract"),
        ("matcher.insufficient_inliers", None),
    ]
    assert _frame_records(out)[0]["payload"]["error"] == "SystemExit: 3"
    assert "running" not in json.loads((out / RUN_MARK).read_text())
    assert json.loads((out / "report.json").read_text())["frames_done"] == 2


@contextmanager
def _sigterm_exits(status: int) -> Iterator[None]:
    """SIGTERM handled as flight software handles it: ``sys.exit(status)`` in its handler."""

    def on_term(signum: int, frame: object) -> None:
        sys.exit(status)

    previous = signal.signal(signal.SIGTERM, on_term)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_the_hosts_sys_exit_during_a_frame_reaches_it_with_the_frame_recorded(
    small_flight: SmallFlight, tmp_path: Path
) -> None:
    """SIGTERM lands while the backend extracts the first frame's query (raised there, so the
    handler runs at that point): the run ends with the handler's ``SystemExit``, no candidate
    dropped and no contract error for it; the frame has its ``matcher.interrupted`` record and
    its one health update (no fix)."""
    flown: list[PipelineMatcher] = []
    with _sigterm_exits(143), pytest.raises(SystemExit) as caught:
        _fly(
            small_flight("sigterm"),
            tmp_path / "out",
            _failing_once(lambda: signal.raise_signal(signal.SIGTERM)),
            flown,
        )
    assert caught.value.code == 143
    (record,) = _frame_records(tmp_path / "out")
    assert record["kind"] == "matcher.interrupted"
    assert record["payload"]["error"] == "SystemExit: 143"
    (matcher,) = flown
    health = matcher.health_snapshot()  # one update, of no fix
    assert (health.consecutive_low_inlier, health.mean_inliers_60s) == (1, 0.0)
