"""The tools' run layer, which replay, eval, bench, features, the reports and the GeoJSON
export build on: typed run records (:class:`FrameOutcome`, :class:`FlightRun`), opening a
matcher for a strategy with :class:`Overrides` (:func:`prepare_matcher`, composed before a run
touches its directory, :func:`open_matcher`, :func:`compose_matcher`, :func:`open_backend`),
flying a flight (:func:`run_flight`, :func:`fly`), scoring it against ground truth and
telemetry (:func:`summarize`, :func:`result_fingerprint`) and writing a run's files, each one
atomically (:mod:`c3_matcher.atomic`). Commands live beside it (``replay``,
``evaluate``, ``bench``); nothing here is one."""

from c3_matcher_tools.run.evaluation import (
    StrategyEval,
    StrategyFailure,
    StrategyRow,
    SummaryRow,
)
from c3_matcher_tools.run.flight import (
    ALL_FRAMES,
    FlightOptions,
    FlightStopped,
    Progress,
    check_flight,
    fly,
    fly_prepared,
    run_flight,
    signals_noted,
)
from c3_matcher_tools.run.matcher import (
    NO_OVERRIDES,
    ComposedMatcher,
    Overrides,
    PreparedMatcher,
    compose_matcher,
    open_backend,
    open_matcher,
    prepare_matcher,
)
from c3_matcher_tools.run.outputs import (
    EVAL_OUT,
    REPLAY_OUT,
    RunFiles,
    check_output_dirs,
    exclusive_output_dir,
    flight_report,
    forget_previous_run,
    output_dir_name,
    write_flight_outputs,
    write_html_report,
    write_results,
)
from c3_matcher_tools.run.records import FlightRun, FrameOutcome
from c3_matcher_tools.run.scoring import (
    RunSummary,
    TelemetryReference,
    best_candidate_error,
    figure,
    result_fingerprint,
    summarize,
    telemetry_reference,
    truth_position,
)

__all__ = [
    "ALL_FRAMES",
    "EVAL_OUT",
    "NO_OVERRIDES",
    "REPLAY_OUT",
    "ComposedMatcher",
    "FlightOptions",
    "FlightRun",
    "FlightStopped",
    "FrameOutcome",
    "Overrides",
    "PreparedMatcher",
    "Progress",
    "RunFiles",
    "RunSummary",
    "StrategyEval",
    "StrategyFailure",
    "StrategyRow",
    "SummaryRow",
    "TelemetryReference",
    "best_candidate_error",
    "check_flight",
    "check_output_dirs",
    "compose_matcher",
    "exclusive_output_dir",
    "figure",
    "flight_report",
    "fly",
    "fly_prepared",
    "forget_previous_run",
    "open_backend",
    "open_matcher",
    "output_dir_name",
    "prepare_matcher",
    "result_fingerprint",
    "run_flight",
    "signals_noted",
    "summarize",
    "telemetry_reference",
    "truth_position",
    "write_flight_outputs",
    "write_html_report",
    "write_results",
]
