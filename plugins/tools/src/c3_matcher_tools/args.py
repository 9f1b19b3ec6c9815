"""Argument types and options the ground commands share (a bad value is a usage error, exit 2,
naming the option)."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

__all__ = [
    "add_attitude_noise_option",
    "add_strategies_option",
    "non_negative_float",
]


def add_attitude_noise_option(p: argparse.ArgumentParser) -> None:
    """``--attitude-noise-deg``: replay the flight as an IMU with that much error reports it."""
    p.add_argument(
        "--attitude-noise-deg",
        type=non_negative_float("--attitude-noise-deg"),
        default=0.0,
        help="add seeded Gaussian noise of this sigma (deg) to every frame's roll, pitch and yaw "
        "(an IMU's error; the same per frame in every run; default 0)",
    )


def add_strategies_option(p: argparse.ArgumentParser, help: str) -> None:
    """``--strategy``, repeatable: the strategies a command runs (``None`` when not given)."""
    p.add_argument("--strategy", action="append", default=None, help=help)


def non_negative_float(what: str) -> Callable[[str], float]:
    """An argparse type: a finite float >= 0, else a usage error (exit 2) naming ``what``."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{what}: expected a number, got {text!r}") from None
        if not math.isfinite(value) or value < 0:
            raise argparse.ArgumentTypeError(f"{what}: must be finite and >= 0, got {value}")
        return value

    return parse
