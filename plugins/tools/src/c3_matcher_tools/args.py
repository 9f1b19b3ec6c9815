"""Argument types and options the ground commands share (a bad value is a usage error, exit 2,
naming the option)."""

from __future__ import annotations

import argparse
import dataclasses
import math
from collections.abc import Callable
from typing import TYPE_CHECKING

from c3_matcher.commands import bounded_float, bounded_int
from c3_matcher.errors import InvalidInputError

if TYPE_CHECKING:
    from c3_matcher_tools.dataset.format import FlightDataset

__all__ = [
    "SEED_RANGE",
    "add_attitude_noise_option",
    "add_seed_option",
    "add_strategies_option",
    "apply_attitude_noise",
    "non_negative_float",
]

SEED_RANGE = (0, 2**32 - 1)
"""The seeds a command's ``--seed`` takes (a generator's seed is never negative)."""


def add_attitude_noise_option(p: argparse.ArgumentParser) -> None:
    """``--attitude-noise-deg``: replay the flight as an IMU with that much error reports it."""
    p.add_argument(
        "--attitude-noise-deg",
        type=non_negative_float(),
        default=0.0,
        help="add seeded Gaussian noise of this sigma (deg) to every frame's roll, pitch and yaw "
        "(an IMU's error; the same per frame in every run; default 0); a roll or pitch it "
        "pushes outside [-90, 90] deg is refused before the run starts, naming the frame",
    )


def apply_attitude_noise(
    dataset: FlightDataset, sigma_deg: float, first: int | None = None
) -> FlightDataset:
    """``dataset`` as ``--attitude-noise-deg sigma_deg`` replays it
    (:func:`~c3_matcher_tools.dataset.format.with_attitude_noise`), every frame's noisy attitude
    checked now, before anything is written or loaded: a yaw pushed past +-360 deg is wrapped
    (the same heading); a roll or pitch pushed outside [-90, 90] deg is refused,
    ``InvalidInputError`` naming the option, the frame and the angle in degrees. ``first``: only
    the first N frames are checked (a run that flies only those)."""
    from c3_matcher_tools.dataset.format import with_attitude_noise

    noisy = with_attitude_noise(dataset, sigma_deg)
    if noisy is dataset:
        return dataset
    frames = []
    checked = len(dataset.frames) if first is None else first
    for n, (frame, recorded) in enumerate(zip(noisy.frames, dataset.frames, strict=True)):
        if n >= checked:  # never flown
            frames.append(frame)
            continue
        roll, pitch, yaw = frame.attitude_deg
        for name, value, was in (
            ("roll", roll, recorded.attitude_deg[0]),
            ("pitch", pitch, recorded.attitude_deg[1]),
        ):
            if not (math.isfinite(value) and -90.0 <= value <= 90.0):
                raise InvalidInputError(
                    "--attitude-noise-deg",
                    f"{sigma_deg:g} deg (1 sigma) puts frame {frame.index} ({frame.image}) at "
                    f"{name} {_deg(value)} deg (recorded {_deg(was)}), outside [-90, 90]: "
                    "choose a smaller sigma",
                )
        if not math.isfinite(yaw):
            raise InvalidInputError(
                "--attitude-noise-deg",
                f"{sigma_deg:g} deg (1 sigma) puts frame {frame.index} ({frame.image}) at yaw "
                f"{yaw} deg: choose a smaller sigma",
            )
        if not -360.0 <= yaw <= 360.0:  # the same heading, in the matcher's range
            yaw = math.fmod(yaw, 360.0)
        frames.append(dataclasses.replace(frame, attitude_deg=(roll, pitch, yaw)))
    return dataclasses.replace(noisy, frames=tuple(frames))


def _deg(value: float) -> str:
    return f"{value:.1f}" if abs(value) < 1e4 else f"{value:.3g}"


def add_seed_option(p: argparse.ArgumentParser, help: str) -> None:
    """``--seed``: the seed of a command's random choices, in :data:`SEED_RANGE` (default 0);
    ``help`` says what it seeds."""
    low, high = SEED_RANGE
    p.add_argument(
        "--seed",
        type=bounded_int(low, high),
        default=0,
        help=f"{help} ({low}..{high}; default 0)",
    )


def add_strategies_option(p: argparse.ArgumentParser, help: str) -> None:
    """``--strategy``, repeatable: the strategies a command runs (``None`` when not given)."""
    p.add_argument("--strategy", action="append", default=None, help=help)


def non_negative_float() -> Callable[[str], float]:
    """An argparse type: a finite float >= 0, else a usage error (exit 2)."""
    return bounded_float(0.0)
