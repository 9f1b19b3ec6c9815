"""``--attitude-noise-deg``: a flight replayed as an IMU with that much error would report it,
the same error per frame in every run, ground truth untouched."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from c3_matcher_tools.dataset.format import load_dataset, with_attitude_noise
from c3_matcher_tools.testing.cli import run_cli

DEMO = Path(__file__).resolve().parents[3] / "data" / "flights" / "naip_demo"


def test_noise_is_seeded_per_frame_and_leaves_truth_alone() -> None:
    flight = load_dataset(DEMO)
    noisy = with_attitude_noise(flight, 2.0)
    again = with_attitude_noise(flight, 2.0)
    cut = dataclasses.replace(flight, frames=flight.frames[5:9])
    assert [f.attitude_deg for f in noisy.frames] == [f.attitude_deg for f in again.frames]
    assert [f.attitude_deg for f in with_attitude_noise(cut, 2.0).frames] == [
        f.attitude_deg for f in noisy.frames[5:9]
    ]
    errors = np.array(
        [np.subtract(n.attitude_deg, f.attitude_deg) for n, f in zip(noisy.frames, flight.frames)]
    )
    assert 1.0 < errors.std() < 3.0 and np.all(errors != 0)
    assert not np.array_equal(
        errors,
        np.array(
            [
                np.subtract(n.attitude_deg, f.attitude_deg)
                for n, f in zip(with_attitude_noise(flight, 2.0, seed=1).frames, flight.frames)
            ]
        ),
    )
    for n, f in zip(noisy.frames, flight.frames, strict=True):
        assert n.candidates == f.candidates and n.pose == f.pose and n.image == f.image
    assert noisy.meta["attitude_noise"] == {"sigma_deg": 2.0, "seed": 0}
    assert with_attitude_noise(flight, 0.0) is flight


@pytest.mark.parametrize("sigma", [-1.0, math.nan, math.inf])
def test_a_bad_sigma_is_refused(sigma: float) -> None:
    with pytest.raises(ValueError, match="attitude noise"):
        with_attitude_noise(load_dataset(DEMO), sigma)


def test_the_cli_refuses_a_negative_sigma(tmp_path: Path) -> None:
    proc = run_cli("eval", DEMO, "--attitude-noise-deg", "-2", cwd=tmp_path, timeout=300)
    assert proc.returncode == 2
    assert "--attitude-noise-deg: must be finite and >= 0" in proc.stderr
