"""``c3-matcher fdr [PATH]``: what a flight-data log holds after a flight, and whether it is
whole (exit 1 when a line is unreadable, a gap has no note or ``seq`` went back; records a note
says another program moved or removed with a live segment are named as not in the log, exit 0)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING

from c3_matcher.commands import EXIT_FAILURE, EXIT_OK
from c3_matcher.fdr.check import FdrCheck, MovedSegment, SeqRange, check_fdr

if TYPE_CHECKING:
    from c3_matcher.commands import CommandRegistry
    from c3_matcher.context import CommandContext

__all__ = ["register_fdr_command"]

_SHOWN = 5  # items of a list a line names before "and N more"
_HELP = "check a flight-data log: records by kind, seq gaps and the notes that explain them"
_DESCRIPTION = (
    "Read every segment of a flight-data log (the live one and its rotated ones) and say what "
    "it holds: records by kind, seq range and wall times, records the recorder let go (each "
    "named by a fdr.records_dropped note), records another program moved or removed with a live "
    "segment (named by a fdr.segment_replaced note: not in this log, but no damage) and any "
    "damage: unreadable lines, seq gaps no note explains, seq going back. Exit 0 when whole, 1 "
    "when damaged."
)


def register_fdr_command(commands: CommandRegistry) -> None:
    p = commands.add("fdr", help=_HELP, description=_DESCRIPTION)
    p.add_argument(
        "path", type=Path, nargs="?", help="the log's live segment (default: [fdr] path)"
    )
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(handler=_cmd_fdr)


def _cmd_fdr(args: argparse.Namespace, ctx: CommandContext) -> int:
    check = check_fdr(args.path or ctx.settings.fdr.path)
    if args.json:
        ctx.out(json.dumps(check.to_json(), indent=2))
    else:
        for line in _describe(check):
            ctx.out(line)
    return EXIT_OK if check.intact else EXIT_FAILURE


def _describe(check: FdrCheck) -> list[str]:
    """``check`` as lines for a person: the verdict, then what the log holds and its damage."""
    segments = check.segments
    lines = [
        f"{check.path}: {'intact' if check.intact else 'damaged'}",
        f"  segments: {len(segments)}"
        + (f" ({segments[0].name} .. {segments[-1].name})" if len(segments) > 1 else ""),
        f"  records: {check.records}"
        + (f", seq {check.seqs}" if check.seqs else "")
        + (f", {check.wall_times[0]} to {check.wall_times[1]}" if check.wall_times else ""),
    ]
    if check.kinds:
        lines.append("  kinds: " + ", ".join(f"{k} {n}" for k, n in check.kinds.items()))
    if check.let_go:
        lines.append(
            f"  let go: {check.let_go} record(s), seqs {_seqs(check.noted_gaps)}, "
            "each named by a fdr.records_dropped note"
        )
    lines += [_moved_away(m) for m in check.moved_away]
    if check.gaps:
        lines.append(f"  gaps no note explains: seqs {_seqs(check.gaps)}")
    if check.wall_went_back:
        lines.append(
            f"  wall clock went back {check.wall_went_back} time(s) between records (a restart "
            "on a computer whose clock was not set?): the times above are the earliest and latest"
        )
    if check.went_back:
        lines.append("  seq went back: " + _some([f"{s} after {p}" for p, s in check.went_back]))
    if check.unreadable:
        lines.append("  unreadable lines: " + _some(list(check.unreadable)))
    if (lost := check.not_in_log) is not None:
        lines.append(
            f"  not in the log: {lost.count} record(s), seqs "
            f"{SeqRange(lost.first_seq, lost.last_seq)}, named in {check.path.name}.lock "
            "(waiting on a full disk, or lost when the recorder stopped: the next recorder at "
            "this path records them)"
        )
    return lines


def _moved_away(moved: MovedSegment) -> str:
    """Where the records went that a live segment removed or renamed took from this log."""
    seqs = f"seqs {moved.missing}" if moved.missing else f"records up to seq {moved.last_seq}"
    segment = f"the live segment {moved.segment}"
    went = (
        f"renamed {segment} to {moved.moved_to}"
        if moved.moved_to
        else f"removed {segment} (or moved it out of its folder)"
    )
    return (
        f"  moved away: {seqs}, not in this log: another program {went} while its recorder "
        "had it open (its fdr.segment_replaced note says so)"
    )


def _seqs(ranges: tuple[SeqRange, ...]) -> str:
    return _some([str(r) for r in ranges]) if ranges else "none between records"


def _some(items: list[str]) -> str:
    """The first few ``items``, then how many more."""
    more = f", and {len(items) - _SHOWN} more" if len(items) > _SHOWN else ""
    return "; ".join(items[:_SHOWN]) + more
