"""Entry point of the ground tools (group ``c3_matcher.plugins``): they plug into the core the
way a third party does, through its hooks: the ground commands (``engines build|bench``,
``tiles``, ``dataset``, ``replay``, ``eval``, ``bench``, ``features``) and the SIFT + MAGSAC
baseline."""

from __future__ import annotations

from c3_matcher.commands import CommandRegistry
from c3_matcher.plugins import StrategySpec, hookimpl

__all__ = ["c3_matcher_register_commands", "c3_matcher_strategies"]


@hookimpl
def c3_matcher_register_commands(commands: CommandRegistry) -> None:
    from c3_matcher_tools.bench import register_bench_command
    from c3_matcher_tools.dataset.cli import register_dataset_command
    from c3_matcher_tools.engines.cli import register_engines_build_commands
    from c3_matcher_tools.evaluate import register_eval_command
    from c3_matcher_tools.features.cli import register_features_command
    from c3_matcher_tools.replay import register_replay_command
    from c3_matcher_tools.tilestore.cli import register_tiles_command

    register_engines_build_commands(commands)
    register_tiles_command(commands)
    register_dataset_command(commands)
    register_replay_command(commands)
    register_eval_command(commands)
    register_bench_command(commands)
    register_features_command(commands)


@hookimpl
def c3_matcher_strategies() -> list[StrategySpec]:
    from c3_matcher_tools.baselines import SIFT_LABEL, SiftOptions, create

    return [
        StrategySpec(
            name=SIFT_LABEL,
            factory=create,
            options_model=SiftOptions,
            description="OpenCV SIFT + ratio test, MAGSAC (classical baseline, ground only)",
            baseline=True,
        )
    ]
