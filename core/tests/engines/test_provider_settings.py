"""The ``[engines]`` provider and directory settings: ``provider_options`` keyed as
``providers`` is (an alias such as ``CUDA``, any case) reaches the session; a key no provider
has, options for the CPU provider (onnxruntime ignores them) or for a provider ``providers``
leaves out are refused, naming the field, never dropped silently. A provider setting that
cannot be met, or an engine directory that is a file, is a configuration error (exit 2) naming
the setting, not an engine to build."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.config import load_settings
from c3_matcher.engines.runtime import OnnxInferenceRuntime, ProviderSettings, provider_options
from c3_matcher.errors import ConfigurationError

CUDA = "CUDAExecutionProvider"
CPU = "CPUExecutionProvider"
DEMO = Path(__file__).resolve().parents[3] / "data" / "demo"
OPTIONS = {"cudnn_conv_algo_search": "EXHAUSTIVE", "gpu_mem_limit": 1 << 30}


def _env(options: str, providers: str | None = '["CUDA", "CPU"]') -> dict[str, str]:
    env = {"C3_MATCHER_ENGINES__PROVIDER_OPTIONS": options}
    if providers is not None:
        env["C3_MATCHER_ENGINES__PROVIDERS"] = providers
    return env


@pytest.mark.parametrize("key", ["CUDA", "cuda", "CUDAExecutionProvider", "cudaexecutionprovider"])
def test_options_keyed_by_an_alias_reach_the_session(
    key: str, tiny_engine: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import onnxruntime as ort

    settings = load_settings(
        env=_env(
            f'{{"{key}": {{"cudnn_conv_algo_search": "EXHAUSTIVE", "gpu_mem_limit": 1073741824}}}}'
        )
    )
    assert settings.engines.provider_options == {CUDA: OPTIONS}
    asked: list[Any] = []
    real = ort.InferenceSession

    def recording(path: str, **kwargs: Any) -> Any:
        asked.append(kwargs["providers"])
        return real(path, **kwargs)

    monkeypatch.setattr(ort, "InferenceSession", recording)
    runtime = OnnxInferenceRuntime.from_settings(settings.engines, providers_available=[CUDA, CPU])
    runtime.load_engine(tiny_engine)  # CUDA is not there: the session falls back to the CPU
    assert asked == [[(CUDA, OPTIONS), CPU]]


def test_options_given_in_code_by_an_alias_apply_too() -> None:
    got = provider_options([CUDA, CPU], None, ProviderSettings(extra={"cuda": {"a": 1}}))
    assert got == [(CUDA, {"cudnn_conv_algo_search": "DEFAULT", "a": 1}), CPU]


@pytest.mark.parametrize(
    ("options", "providers", "needles"),
    [
        ('{"CUDAExecutionProvidr": {"a": 1}}', '["CUDA", "CPU"]', ["CUDAExecutionProvidr"]),
        ('{"Quantum": {"a": 1}}', None, ["Quantum", "unknown execution provider"]),
        ('{"CPU": {"a": 1}}', None, ["CPU provider", "intra_op_threads", "cpu_mem_arena"]),
        ('{"cuda": {}, "CUDAExecutionProvider": {}}', None, ["'cuda'", "both name"]),
        ('{"OpenVINO": {"a": 1}}', '["CUDA", "CPU"]', ["OpenVINO", "providers", "never apply"]),
    ],
    ids=["misspelt", "unknown", "cpu", "twice", "not-listed"],
)
def test_options_that_would_never_apply_are_refused_naming_the_field(
    options: str, providers: str | None, needles: list[str]
) -> None:
    with pytest.raises(ConfigurationError) as info:
        load_settings(env=_env(options, providers))
    assert info.value.problems[0][0] == "engines.provider_options"
    assert all(needle in str(info.value) for needle in needles), str(info.value)


def test_cpu_options_given_in_code_are_refused_not_dropped() -> None:
    with pytest.raises(ConfigurationError, match="intra_op_threads"):
        provider_options([CPU], None, ProviderSettings(extra={CPU: {"a": 1}}))


def test_an_unmet_provider_setting_is_a_configuration_error() -> None:
    with pytest.raises(ConfigurationError) as info:
        OnnxInferenceRuntime([CPU], requested=["CUDA"])
    message = str(info.value)
    assert "[engines] providers" in message and "none of ['CUDAExecutionProvider']" in message
    assert "build it" not in message and not message.startswith("engine ")


@pytest.fixture
def clean_env(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    for key in [k for k in os.environ if k.upper().startswith("C3_MATCHER_")]:
        monkeypatch.delenv(key)
    monkeypatch.setenv("C3_MATCHER_FDR__PATH", str(tmp_path / "fdr.jsonl"))
    return tmp_path


def test_match_with_no_installed_provider_exits_2_naming_the_setting(
    clean_env: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from c3_matcher.cli import main

    monkeypatch.setenv("C3_MATCHER_ENGINES__PROVIDERS", '["CUDA"]')
    argv = ["match", "--query", str(DEMO / "frame.jpg"), "--tile", str(DEMO / "tile_a.png")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("c3-matcher: invalid configuration"), err
    assert "[engines] providers (C3_MATCHER_ENGINES__PROVIDERS)" in err
    assert "build it" not in err


@pytest.mark.parametrize("below", [False, True], ids=["the-file", "below-a-file"])
@pytest.mark.parametrize("command", [["engines", "list"], ["engines", "verify"]])
def test_an_engine_directory_that_is_a_file_is_refused(
    clean_env: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    command: list[str],
    below: bool,
) -> None:
    from c3_matcher.cli import main

    a_file = clean_env / "engines"
    a_file.write_text("not a directory")
    directory = a_file / "sub" if below else a_file
    monkeypatch.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(directory))
    assert main(command) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "engines.directory" in err and f"{directory} is not a directory" in err, err
    with pytest.raises(ConfigurationError, match="engines.tensorrt_cache_dir"):
        load_settings(env={"C3_MATCHER_ENGINES__TENSORRT_CACHE_DIR": str(a_file)})
