"""Accuracy and latency of the default strategy over the real-path scenarios at several keypoint
budgets (the measurement behind the max_keypoints default, DECISIONS 14).

    .venv/bin/python scripts/sweep_keypoints.py [BUDGET ...]     # default: 512 1024 2048
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from loguru import logger

from c3_matcher.compose import build_default_helpers, compose_root
from c3_matcher.config import C3Settings
from c3_matcher.fdr import InMemoryFdr
from c3_matcher_tools.sim.scenario import build_scenario
from c3_matcher_tools.testing.realpath import run_scenario, scenario_specs

REPO = Path(__file__).resolve().parents[1]


def main(budgets: list[int]) -> None:
    logger.remove()
    scenarios = [(build_scenario(spec), order) for spec, order in scenario_specs()]
    print(
        f"{'budget':>6} {'scenario':52} {'best ok':>7} {'inliers':>7} {'mean err':>8} "
        f"{'s/frame':>7}"
    )
    for budget in budgets:
        settings = C3Settings(
            engines={"directory": REPO / ".engines"},
            matcher={"max_keypoints": budget, "tile_cache_size": 0},
        )
        root = compose_root(
            settings,
            {**build_default_helpers(settings), "c13_fdr": InMemoryFdr()},
            configure_logs=False,
        )
        for scenario, order in scenarios:
            t0 = time.perf_counter()
            o = run_scenario(root.matcher, scenario, order)
            print(
                f"{budget:6d} {o.name:52} {o.true_tile_best!s:>7} {o.inliers:7d} "
                f"{o.mean_error_px:8.2f} {time.perf_counter() - t0:7.1f}",
                flush=True,
            )


if __name__ == "__main__":
    main([int(x) for x in sys.argv[1:]] or [512, 1024, 2048])
