"""A plugin that misbehaves in flight does not break the frame's contract: whatever its backend
raises (its own ``BaseException`` and ``sys.exit()`` included) ends as the contract's error with
the frame's terminal record and one health update; a stop (Ctrl-C, the host's ``sys.exit`` from
its signal handler) still reaches the caller after the frame's one health update and its record,
none when the stop cut a write short; a ``provenance()`` that raises, returns no mapping or names
the core's own record fields neither loses the frame nor changes its record."""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator, Mapping
from typing import Any

import pytest

import c3_matcher.pipeline
from c3_matcher.errors import InsufficientInliersError, MatcherBackboneError
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.features import Features, RawMatches
from c3_matcher.prepared import PreparedImage
from c3_matcher.stages.frame_records import TERMINAL_RECORD_FIELDS
from c3_matcher.testing import FakeBackend, ScriptedCandidate, ScriptedRig

from .host_exit import HOST_STATUS, ctrl_c, host_exit, host_handler

S = ScriptedCandidate
TERMINAL = (
    "matcher.frame_done",
    "matcher.insufficient_inliers",
    "matcher.invalid_input",
    "matcher.interrupted",
)


class Abort(BaseException):
    """A plugin's own ``BaseException``."""


Raise = BaseException | Callable[[], object]
"""What a step raises: an exception, or what raises one when called (a stop, as it is raised)."""


@pytest.fixture(autouse=True)
def _the_hosts_handler() -> Iterator[None]:
    """The host's signal handler that exits, installed for every test: a plugin's own
    ``sys.exit`` is its failure even in a host that has one."""
    with host_handler():
        yield


def _fire(raised: Raise) -> None:
    if isinstance(raised, BaseException):
        raise raised
    raised()


class Misbehaving:
    """The fake backend, but its ``extract`` raises ``on_query`` on the query frame and
    ``on_tile[i]`` on tile ``i``, and its ``provenance`` is ``provenance``."""

    def __init__(
        self,
        inner: FakeBackend,
        *,
        on_query: Raise | None = None,
        on_tile: Mapping[int, Raise] | None = None,
        provenance: Callable[[], Any] | None = None,
    ) -> None:
        self.inner = inner
        self.label, self.input_rule = inner.label, inner.input_rule
        self.extract_phase, self.match_phase = inner.extract_phase, inner.match_phase
        self.on_query, self.on_tile = on_query, dict(on_tile or {})
        self._provenance = provenance or inner.provenance

    def extract(self, image: PreparedImage) -> Features:
        mark = int(image.image.max())  # tile i is i + 1, the query 255
        raised = self.on_query if image.calibration is not None else self.on_tile.get(mark - 1)
        if raised is not None:
            _fire(raised)
        return self.inner.extract(image)

    def match(self, query: Features, tile: Features) -> RawMatches:
        return self.inner.match(query, tile)

    def provenance(self) -> Any:
        return self._provenance()


def _rig(fdr: InMemoryFdr, script: list[ScriptedCandidate], **misbehaviour: Any) -> ScriptedRig:
    return ScriptedRig(script, fdr, wrap_backend=lambda inner: Misbehaving(inner, **misbehaviour))


def _terminal(fdr: InMemoryFdr) -> list[tuple[str, dict[str, Any]]]:
    """The frame's terminal records (a backbone error of no candidate is one)."""
    return [
        (kind, p)
        for kind, p in fdr.records
        if kind in TERMINAL or (kind == "matcher.backbone_error" and p["tile_id"] is None)
    ]


OWN = [RuntimeError("backend gave up"), Abort("plugin abort"), SystemExit("plugin quit")]
OWN_IDS = ["an exception", "a plugin's own BaseException", "a plugin's own sys.exit"]
"""What a plugin raises of its own: its step's failure, its ``sys.exit()`` (no handler's) too."""


@pytest.mark.parametrize("raised", OWN, ids=OWN_IDS)
def test_a_base_exception_on_the_query_is_the_contract_error_with_its_record(fdr, logs, raised):
    rig = _rig(fdr, [S(120)], on_query=raised)
    with pytest.raises(MatcherBackboneError) as caught:
        rig.match()
    assert caught.value.phase == "query_extract" and caught.value.cause is raised
    ((kind, record),) = _terminal(fdr)
    assert kind == "matcher.backbone_error" and record["phase"] == "query_extract"
    assert record["error"] == f"{type(raised).__name__}: {raised}"
    assert rig.health.update_count == 1 and rig.health.last_update.had_backbone_error


@pytest.mark.parametrize("raised", OWN, ids=OWN_IDS)
def test_a_base_exception_on_a_tile_drops_only_that_candidate(fdr, logs, raised):
    rig = _rig(fdr, [S(120), S(150)], on_tile={1: raised})
    result = rig.match()
    assert [m.inlier_count for m in result.per_candidate] == [120]
    (drop,) = [p for p in fdr.of_kind("matcher.backbone_error") if p["tile_id"] is not None]
    assert drop["candidate_index"] == 1 and drop["phase"] == "disk_forward"
    assert drop["error"] == f"{type(raised).__name__}: {raised}"
    ((kind, done),) = _terminal(fdr)
    assert kind == "matcher.frame_done" and done["candidates_dropped"] == 1
    assert rig.health.update_count == 1


@pytest.mark.parametrize(
    "raised",
    [
        Abort("plugin abort"),
        SystemExit("plugin quit"),
        InsufficientInliersError("f", 0, 60, 1, 1, "x"),
    ],
    ids=[
        "a plugin's own BaseException",
        "a sys.exit no handler raised",
        "a contract error not the matcher's own",
    ],
)
def test_anything_else_raised_inside_the_matcher_is_an_internal_backbone_error(
    fdr, logs, monkeypatch, raised
):
    def ranked(survivors: Any) -> Any:
        raise raised

    monkeypatch.setattr(c3_matcher.pipeline, "ranked", ranked)
    rig = _rig(fdr, [S(120)])
    with pytest.raises(MatcherBackboneError) as caught:
        rig.match()
    assert caught.value.phase == "internal" and caught.value.cause is raised
    ((kind, record),) = _terminal(fdr)
    assert kind == "matcher.backbone_error" and record["phase"] == "internal"
    assert record["error"].startswith(type(raised).__name__)
    assert rig.health.update_count == 1


STOPS = [
    pytest.param(ctrl_c, KeyboardInterrupt, id="Ctrl-C"),
    pytest.param(host_exit, SystemExit, id="the host's handler's sys.exit"),
]


def _raising(stop: Callable[[], object], where: str) -> dict[str, Any]:
    """The misbehaviour that raises ``stop`` in the step ``where`` names."""
    if where == "query":
        return {"on_query": stop}
    if where == "a tile":
        return {"on_tile": {1: stop}}
    return {"provenance": stop}


@pytest.mark.parametrize(("stop", "stopped"), STOPS)
@pytest.mark.parametrize("where", ["query", "a tile", "provenance"])
def test_a_stop_goes_on_to_the_caller_with_the_frame_recorded_first(
    fdr, logs, stop, stopped, where
):
    """A stop raised in any of a plugin's steps is no failure of that step (no candidate
    dropped, no contract error): the frame's one health update and its ``matcher.interrupted``
    record, then the stop itself reaches the caller."""
    misbehaviour = _raising(stop, where)
    rig = _rig(fdr, [S(120), S(150)], **misbehaviour)
    with pytest.raises(stopped) as caught:
        rig.match()
    if stopped is SystemExit:
        assert caught.value.code == HOST_STATUS
    ((kind, record),) = _terminal(fdr)
    assert kind == "matcher.interrupted"
    assert record["frame_id"] == str(rig.frame.frame_id)
    assert record["error"] == f"{stopped.__name__}: {caught.value}"
    assert rig.health.update_count == 1 and rig.health.last_update.best_inlier_count == 0
    assert not fdr.of_kind("matcher.backbone_error")  # a stop is no backbone failure


@pytest.mark.parametrize(("stop", "stopped"), STOPS)
def test_a_stop_inside_the_matchers_own_code_goes_on(fdr, logs, monkeypatch, stop, stopped):
    """The host's signal handler may run anywhere in the frame, in the core's own code too."""

    def ranked(survivors: Any) -> Any:
        return stop()

    monkeypatch.setattr(c3_matcher.pipeline, "ranked", ranked)
    rig = _rig(fdr, [S(120)])
    with pytest.raises(stopped):
        rig.match()
    assert [kind for kind, _ in _terminal(fdr)] == ["matcher.interrupted"]
    assert rig.health.update_count == 1


class StoppedInWrite(InMemoryFdr):
    """An FDR client (of the test's module, as an embedding's would be) that a stop ends while
    it writes a record of ``kind``: after the line (the frame's last write) or before it."""

    def __init__(self, kind: str, stop: Callable[[], object], *, after: bool) -> None:
        super().__init__()
        self.kind, self.stop, self.after = kind, stop, after

    def record(self, kind: str, payload: Mapping[str, Any]) -> None:
        if kind == self.kind and not self.after:
            self.stop()
        super().record(kind, payload)
        if kind == self.kind:
            self.stop()


@pytest.mark.parametrize(("stop", "stopped"), STOPS)
def test_a_stop_that_cut_the_success_write_short_adds_no_record_after_it(stop, stopped):
    fdr = StoppedInWrite("matcher.frame_done", stop, after=True)
    rig = _rig(fdr, [S(120)])
    with pytest.raises(stopped):
        rig.match()
    assert [kind for kind, _ in _terminal(fdr)] == ["matcher.frame_done"]
    assert rig.health.update_count == 1


@pytest.mark.parametrize(("stop", "stopped"), STOPS)
def test_a_stop_that_cut_a_candidates_write_short_still_updates_health_once(stop, stopped):
    """Ended inside a dropped candidate's record (not the frame's last write): no record after
    the torn one, and the frame's health update all the same, since it writes no record."""
    fdr = StoppedInWrite("matcher.backbone_error", stop, after=False)
    rig = _rig(fdr, [S(120), S(150)], on_tile={1: RuntimeError("extractor down")})
    with pytest.raises(stopped):
        rig.match()
    assert fdr.records == []  # nothing written after the write the stop cut short
    assert rig.health.update_count == 1
    assert rig.health.last_update.best_inlier_count == 0
    assert rig.health.last_update.had_backbone_error  # the candidate's failure counted


def _raises() -> Any:
    raise RuntimeError("provenance unavailable")


@pytest.mark.parametrize(
    ("provenance", "said"),
    [
        (_raises, "provenance() raised RuntimeError: provenance unavailable"),
        (lambda: ["opencv"], "provenance() returned list, not a mapping"),
        (lambda: (_ for _ in ()).throw(Abort("no")), "provenance() raised Abort: no"),
        (lambda: sys.exit("no"), "provenance() raised SystemExit: no"),
    ],
    ids=["raises", "not a mapping", "its own BaseException", "its own sys.exit"],
)
def test_a_provenance_that_cannot_be_read_loses_no_frame(fdr, logs, provenance, said):
    rig = _rig(fdr, [S(120)], provenance=provenance)
    for _ in range(2):
        result = rig.match()
        assert result.per_candidate[0].inlier_count == 120
    done = fdr.of_kind("matcher.frame_done")
    assert [d["provenance_error"] for d in done] == [said, said]
    assert [d["best_inlier_count"] for d in done] == [120, 120]
    assert rig.health.update_count == 2 and rig.health.last_update.best_inlier_count == 120
    assert not fdr.of_kind("matcher.backbone_error")
    (warning,) = logs.of_kind("c3.matcher.provenance_unreadable")  # once, not every frame
    assert said in warning["message"]
    assert rig.pipeline.provenance() == {"provenance_error": said}


def test_a_provenance_that_cannot_be_read_keeps_the_no_fix_error(fdr, logs):
    rig = _rig(fdr, [S(30)], provenance=_raises)
    with pytest.raises(InsufficientInliersError):
        rig.match()
    (record,) = fdr.of_kind("matcher.insufficient_inliers")
    assert record["provenance_error"].endswith("provenance unavailable")
    assert rig.health.update_count == 1 and not rig.health.last_update.had_backbone_error


def test_provenance_never_replaces_the_cores_own_fields(fdr, logs):
    hostile = {
        "threshold": 1,
        "timings_ms": {},
        "frame_id": "forged",
        "best_inlier_count": 10**6,
        "candidate_features": ["stored"],
        "provenance_error": "none",
        "provider": "opencv",
    }
    rig = _rig(fdr, [S(120)], provenance=lambda: hostile)
    rig.match()
    rig.match()
    for done in fdr.of_kind("matcher.frame_done"):
        assert done["threshold"] == 60 and done["best_inlier_count"] == 120
        assert done["frame_id"] == str(rig.frame.frame_id) and "total" in done["timings_ms"]
        assert done["candidate_features"] == ["extracted"] and "provenance_error" not in done
        assert done["provider"] == "opencv"  # its own keys stay
    (warning,) = logs.of_kind("c3.matcher.provenance_reserved")  # said once
    assert warning["keys"] == sorted(set(hostile) - {"provider"})
    assert "Misbehaving" in warning["message"] and "fake_backend" in warning["strategy"]
    assert rig.pipeline.provenance() == {"provider": "opencv"}  # as its records carry it


def test_every_field_a_terminal_record_writes_is_declared_the_cores(fdr):
    rig = _rig(fdr, [S(120), S(0), S(fail_extract=True)], provenance=lambda: {})
    rig.match()
    with pytest.raises(InsufficientInliersError):
        _rig(fdr, [S(30)], provenance=lambda: {}).match()
    for kind in ("matcher.frame_done", "matcher.insufficient_inliers"):
        (record,) = fdr.of_kind(kind)
        assert set(record) <= TERMINAL_RECORD_FIELDS, set(record) - TERMINAL_RECORD_FIELDS
