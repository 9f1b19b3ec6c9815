"""What a third-party plugin author meets, outside the happy path: every name the guide uses is
importable from ``c3_matcher.plugins``, a hook returning the wrong shape and a strategy that
failed to load are named in the errors, and the contract kit fails a backend that lacks a member,
keeps keypoints where the image is masked out, or gives confidences outside [0, 1]."""

from __future__ import annotations

import dataclasses
import types
from typing import Any

import cv2
import numpy as np
import pytest
from pydantic import BaseModel

from c3_matcher import plugins as c3
from c3_matcher.errors import UnknownStrategyError
from c3_matcher.features import Features, RawMatches
from c3_matcher.pipeline import FeatureBackend
from c3_matcher.plugins.manager import PluginSource
from c3_matcher.plugins.types import StrategyDefaults
from c3_matcher.prepared import PreparedImage
from c3_matcher.profiles import BuildProfile
from c3_matcher.testing.contract import BackendContract
from c3_matcher.testing.scripted import ScriptedBackend

from .test_contract_kit import OpenCvBackend

RESEARCH = BuildProfile.from_data({"name": "research", "strict": False, "flags": {}}, "test")


def _create(**_: Any) -> Any:
    raise AssertionError("never created here")


def _plugin(name: str, hook: Any) -> PluginSource:
    module = types.SimpleNamespace(c3_matcher_strategies=c3.hookimpl(hook))
    return PluginSource(name, f"dist-{name}", "1.0", module=module)


def test_strategy_defaults_come_from_the_one_module() -> None:
    assert c3.StrategyDefaults is StrategyDefaults and "StrategyDefaults" in c3.__all__
    spec = c3.StrategySpec("mine", _create, defaults=c3.StrategyDefaults(photometric="clahe"))
    assert spec.defaults.photometric == "clahe"


def test_a_hook_returning_one_spec_instead_of_a_list_is_named() -> None:
    host = c3.PluginHost(RESEARCH, [_plugin("single", lambda: c3.StrategySpec("single", _create))])
    (error,) = host.errors
    assert "expected a list of StrategySpec" in str(error) and "single" in str(error)
    assert host.strategies() == {}


def test_an_options_model_that_is_not_pydantic_is_named_at_load() -> None:
    """A dataclass as the options model: it was listed as healthy and its first run said
    "internal error: AttributeError ... model_validate" without naming the plugin."""

    @dataclasses.dataclass
    class Opts:
        n: int = 1

    spec = lambda: [c3.StrategySpec("mine", _create, options_model=Opts)]  # noqa: E731
    host = c3.PluginHost(RESEARCH, [_plugin("mine", spec)])
    (error,) = host.errors
    assert "not a pydantic model" in str(error) and "dist-mine" in str(error)
    assert host.strategies() == {}


@pytest.mark.parametrize("fault", [KeyError, TypeError])
def test_an_options_validator_that_fails_is_a_configuration_error_naming_the_table(
    fault: type[Exception],
) -> None:
    """A validator raising what pydantic does not turn into a validation error (a KeyError, a
    TypeError) crashed every command with a traceback, ``plugins`` included, and even where
    another strategy was selected."""
    from pydantic import BaseModel, field_validator

    from c3_matcher.cli import _options_as_read
    from c3_matcher.config import C3Settings
    from c3_matcher.errors import ConfigurationError
    from c3_matcher.strategy_options import check_options_tables

    class Opts(BaseModel):
        cross_check: bool = True

        @field_validator("cross_check")
        @classmethod
        def _needs(cls, value: bool) -> bool:
            if not value:
                raise fault("cross_check off needs a table we do not have")
            return value

    host = c3.PluginHost(
        RESEARCH, [_plugin("mine", lambda: [c3.StrategySpec("mine", _create, options_model=Opts)])]
    )
    settings = C3Settings(matcher={"options": {"mine": {"cross_check": False}}})
    assert _options_as_read(settings, host) == settings  # as given: refused where checked
    with pytest.raises(ConfigurationError) as refused:
        check_options_tables(settings, host)
    said = str(refused.value)
    assert "matcher.options.mine" in said and "options model failed" in said
    assert "cross_check off needs a table" in said


def test_unknown_strategy_names_the_plugin_that_failed_to_load() -> None:
    def broken() -> list[Any]:
        raise ImportError("No module named 'not_a_module'")

    host = c3.PluginHost(RESEARCH, [_plugin("mine", broken)])
    with pytest.raises(UnknownStrategyError) as info:
        host.resolve("mine")
    said = str(info.value)
    assert "no strategy is installed" in said and "choose one of" not in said
    assert "not_a_module" in said and "dist-mine" in said and "c3-matcher plugins" in said
    assert info.value.strategy == "mine" and info.value.known == ()


def test_unknown_strategy_without_load_errors_is_unchanged() -> None:
    host = c3.PluginHost(RESEARCH, [_plugin("ok", lambda: [c3.StrategySpec("ok", _create)])])
    with pytest.raises(UnknownStrategyError) as info:
        host.resolve("ko")
    assert str(info.value) == "strategy 'ko' is not recognized, choose one of: ok"


class NoMatchPhase:
    """A backend that forgot a member (it would pass start-up and fail the first frame)."""

    label, extract_phase = "x", "x_detect"
    input_rule = c3.InputRule(max_long_side=1024, multiple=1)

    def __init__(self) -> None:
        self._inner = OpenCvBackend(cv2.AKAZE_create(), cv2.NORM_HAMMING, "x")

    def extract(self, image: PreparedImage) -> Features:
        return self._inner.extract(image)

    def match(self, query: Features, tile: Features) -> RawMatches:
        return self._inner.match(query, tile)

    def provenance(self) -> dict[str, Any]:
        return {"engines": {}}


class RuleAsTuple(NoMatchPhase):
    """Every member, but the input rule written as a (max side, multiple) tuple: each frame
    failed on it (and the start-up probe passed it over)."""

    match_phase = "x_match"
    input_rule = (1024, 16)  # type: ignore[assignment]


class IgnoresTheMask(OpenCvBackend):
    """Keypoints on nodata, padding and warp borders: the mask is never passed."""

    def extract(self, image: PreparedImage) -> Features:
        everywhere = np.ones_like(image.valid)
        return super().extract(PreparedImage(image.image, everywhere, np.eye(3), (1, 1)))


class NegativeConfidences(OpenCvBackend):
    """``1 - distance / 256`` copied from a 32-byte ORB backend onto 61-byte AKAZE ones."""

    def match(self, query: Features, tile: Features) -> RawMatches:
        raw = super().match(query, tile)
        return RawMatches(raw.matches, np.full(len(raw), -0.5, np.float32))


def _kit(make: Any) -> BackendContract:
    class Kit(BackendContract):
        def make_backend(self) -> FeatureBackend:
            backend: FeatureBackend = make()
            return backend

    return Kit()


def _akaze(cls: type[OpenCvBackend]) -> Any:
    return lambda: cls(cv2.AKAZE_create(), cv2.NORM_HAMMING, "akaze_bf")


def test_kit_names_a_missing_member() -> None:
    with pytest.raises(AssertionError, match="NoMatchPhase lacks match_phase"):
        _kit(NoMatchPhase).test_backend_has_every_member()
    with pytest.raises(TypeError, match=r"lacks match_phase .*docs/plugins\.md"):
        ScriptedBackend(NoMatchPhase(), [])  # type: ignore[arg-type]
    _kit(_akaze(OpenCvBackend)).test_backend_has_every_member()


def test_kit_fails_keypoints_where_the_image_is_masked_out() -> None:
    with pytest.raises(AssertionError, match="where image.valid is False"):
        _kit(_akaze(IgnoresTheMask)).test_backend_keeps_keypoints_on_valid_pixels()
    _kit(_akaze(OpenCvBackend)).test_backend_keeps_keypoints_on_valid_pixels()


def test_kit_fails_confidences_outside_zero_one() -> None:
    with pytest.raises(AssertionError, match=r"outside \[0, 1\]"):
        _kit(_akaze(NegativeConfidences)).test_backend_self_match_finds_the_same_points()
    _kit(_akaze(OpenCvBackend)).test_backend_self_match_finds_the_same_points()


def _started(tmp_path: Any, create: Any) -> None:
    """Compose a strategy ``mine`` whose factory is ``create`` (fake helpers, no logging)."""
    from c3_matcher.compose import compose_root
    from c3_matcher.config import C3Settings
    from c3_matcher.testing import fake_helpers

    host = c3.PluginHost(RESEARCH, [_plugin("mine", lambda: [c3.StrategySpec("mine", create)])])
    settings = C3Settings(matcher={"strategy": "mine"}, fdr={"path": tmp_path / "fdr.jsonl"})
    compose_root(settings, fake_helpers(), plugin_host=host, configure_logs=False).close()


def _raising(config: Any, options: Any) -> Any:
    raise RuntimeError("licence file missing")


@pytest.mark.parametrize(
    ("create", "said"),
    [
        (c3.backend_strategy_factory(_raising), "RuntimeError: licence file missing"),
        (lambda **_: NoMatchPhase(), "its factory returned NoMatchPhase, not a matcher"),
        (
            c3.backend_strategy_factory(lambda config, options: NoMatchPhase()),
            "NoMatchPhase is not a FeatureBackend: it lacks match_phase",
        ),
        (
            c3.backend_strategy_factory(lambda config, options: None),
            "NoneType is not a FeatureBackend: it lacks label",
        ),
        (
            c3.backend_strategy_factory(lambda config, options: RuleAsTuple()),
            "RuleAsTuple is not a FeatureBackend: it lacks input_rule as an InputRule "
            "(it is a tuple)",
        ),
    ],
    ids=["factory-raises", "not-a-matcher", "member-missing", "backend-none", "rule-not-a-rule"],
)
def test_a_strategy_that_cannot_start_is_named_with_its_plugin_at_start_up(
    tmp_path: Any, create: Any, said: str
) -> None:
    """Was an internal error, a missing pre-constructed key, or the first frame's failure."""
    from c3_matcher.errors import StrategyStartupError

    with pytest.raises(StrategyStartupError) as info:
        _started(tmp_path, create)
    assert str(info.value).startswith("strategy 'mine' (distribution dist-mine) failed to start: ")
    assert said in str(info.value)


class _BrokenChoice(BaseModel):
    """Options whose declared pair-matcher choice fails when asked (a plugin's own bug)."""

    def matches_with_lightglue(self) -> bool:
        raise RuntimeError("options method broke")


def test_an_options_method_that_fails_at_start_up_is_named_with_its_plugin(
    tmp_path: Any,
) -> None:
    """Asked whether the strategy reads ``[lightglue]``, its options' method raised: the plugin's
    own error came out bare, naming neither the strategy nor its distribution."""
    from c3_matcher.compose import compose_root
    from c3_matcher.config import C3Settings
    from c3_matcher.errors import StrategyStartupError
    from c3_matcher.testing import fake_helpers

    spec = c3.StrategySpec("mine", _create, options_model=_BrokenChoice)
    host = c3.PluginHost(RESEARCH, [_plugin("mine", lambda: [spec])])
    settings = C3Settings(matcher={"strategy": "mine"}, fdr={"path": tmp_path / "fdr.jsonl"})
    with pytest.raises(StrategyStartupError) as info:
        compose_root(settings, fake_helpers(), plugin_host=host, configure_logs=False)
    assert str(info.value) == (
        "strategy 'mine' (distribution dist-mine) failed to start: "
        "RuntimeError: options method broke"
    )


class _NoProvenance(OpenCvBackend):
    """A working AKAZE backend whose provenance cannot be read (a licence server down...)."""

    def provenance(self) -> dict[str, Any]:
        raise RuntimeError("provenance service down")


def test_a_provenance_that_fails_at_start_up_does_not_stop_the_strategy(tmp_path: Any) -> None:
    """Start-up reads the backend's provenance for the provider it logs: read as every frame's
    record reads it, a failure there is the runtime's provider, not a bare error."""
    from c3_matcher.compose import compose_root
    from c3_matcher.config import C3Settings
    from c3_matcher.testing import fake_helpers

    def make(config: Any, options: Any) -> FeatureBackend:
        return _NoProvenance(cv2.AKAZE_create(), cv2.NORM_HAMMING, "akaze_bf")

    spec = c3.StrategySpec("mine", c3.backend_strategy_factory(make))
    host = c3.PluginHost(RESEARCH, [_plugin("mine", lambda: [spec])])
    settings = C3Settings(matcher={"strategy": "mine"}, fdr={"path": tmp_path / "fdr.jsonl"})
    root = compose_root(settings, fake_helpers(), plugin_host=host, configure_logs=False)
    try:
        assert root.matcher.provenance() == {  # type: ignore[attr-defined]
            "provenance_error": "provenance() raised RuntimeError: provenance service down"
        }
    finally:
        root.close()
