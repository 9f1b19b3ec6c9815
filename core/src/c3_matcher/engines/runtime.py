"""``OnnxInferenceRuntime``: the shared ``InferenceRuntime`` (C7) on ONNX Runtime. No PyTorch.

Which execution providers the sessions ask for, and with what options, is
``c3_matcher.engines.providers``; ``intra_op_threads`` sets the session threads. The request is
logged once the sinks are set up (``c3.inference.provider_selected``, ``log_selection``), with a
WARNING ``c3.inference.provider_not_installed`` naming any configured provider the installed
onnxruntime lacks (left out: the matcher runs on the rest); what
each session ACTUALLY uses (``session.get_providers()``: onnxruntime silently falls back to CPU
when a provider cannot start) is logged per engine and is what ``provider`` reports, so the
ready log and every FDR record name the real one; a fallback is a WARNING
``c3.inference.provider_fallback``.

Session options, chosen by measurement (``c3-matcher engines bench --sweep-session-options``;
2-core CPU, onnxruntime 1.31, fresh process per case, 20 runs; peak RSS = VmHWM):

    case                  mem pattern on + arena   off + arena (chosen)   off + no arena
    DISK 512x512          978 MiB                  752 MiB                570 MiB
    DISK 1024x1024        4115 MiB                 3018 MiB               1398 MiB
    LightGlue 2048/side   977 MiB                  600 MiB                683 MiB

- ``enable_mem_pattern = False``: the planner's per-shape pre-allocation cost ~1.1 GB at DISK
  1024x1024 and ~380 MB at LightGlue 2048 for no speed gain (median latencies equal within the
  noise of that sweep). Quiet-machine medians with the chosen options: DISK 512x512 982 ms,
  1024x1024 3810 ms; LightGlue 512/side 312 ms, 2048/side 3286 ms.
- CPU memory arena first kept ON (superseded below): off halves DISK 1024x1024's peak but
  made it markedly slower (2.7x in the sweep; the feasibility study measured 17-40 %), and did
  not help LightGlue's single graph.
- The peak-RSS budget of the airborne default (<= 800 MB) turned the CPU arena OFF by
  default (``[engines] cpu_mem_arena``): disk_lightglue (adaptive LightGlue) on the first two
  frames of ``data/flights/naip_demo``, tile cache off, one process: arena on 818 MiB, 11.7 /
  10.7 CPU s per frame; arena off 584 MiB, 14.2 / 13.2 CPU s (+22 %); arena off for the
  extractors only 806 MiB (+9 %); one shared env arena (kSameAsRequested) 860 MiB. Inlier
  counts identical in all four. ``replay data/flights/naip_demo --limit 4`` peaked at 896 MiB
  (``/usr/bin/time -v``) with the arena on.
- Once DISK's sparse descriptor head removed its 135 MB dense tensor, the arena went back ON
  by default (2026-11-23, ``c3-matcher bench --strategy disk_lightglue``, demo frame, quiet
  machine): new tiles frame p50 3746 -> 3024 ms, peak RSS 494 -> 559 MB (under the 600 MB
  budget); ``replay data/flights/naip_demo --limit 4`` peak 458 -> 468 MB.
- ``graph_optimization_level = ORT_ENABLE_ALL``, sequential execution, ``intra_op_num_threads =
  0`` (one per physical core), ``use_deterministic_compute`` on (bit-identical reruns,
  identical inputs give identical results).
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import onnxruntime as ort
from loguru import logger
from numpy.typing import NDArray

from c3_matcher.engines.manifest import EngineManifest, check_engine_file
from c3_matcher.engines.providers import (
    PROVIDER_ALIASES,
    PROVIDER_CHAIN,
    PROVIDERS_SETTING,
    ProviderSettings,
    configured_providers,
    provider_options,
    providers_not_installed,
    resolve_providers,
    select_providers,
)
from c3_matcher.engines.spec import TensorSpec
from c3_matcher.errors import EngineError
from c3_matcher.logs import log_event

if TYPE_CHECKING:
    from c3_matcher.config import EngineSettings

__all__ = [
    "PROVIDER_ALIASES",
    "PROVIDER_CHAIN",
    "PROVIDER_NOT_INSTALLED",
    "OnnxInferenceRuntime",
    "ProviderSettings",
    "SessionSettings",
    "provider_options",
    "resolve_providers",
    "select_providers",
]

_ORT_TO_NUMPY = {
    "tensor(float)": "float32",
    "tensor(float16)": "float16",
    "tensor(int64)": "int64",
    "tensor(int32)": "int32",
    "tensor(bool)": "bool",
    "tensor(uint8)": "uint8",
}


PROVIDER_NOT_INSTALLED = "c3.inference.provider_not_installed"
"""The WARNING of configured providers the installed onnxruntime lacks (``log_selection``)."""

ORT_ERROR = 3
"""ONNX Runtime's severity level for errors (0 verbose, 1 info, 2 warning, 3 error, 4 fatal)."""


@dataclass(frozen=True, slots=True)
class SessionSettings:
    """ONNX Runtime session options (defaults chosen by measurement, see the module docstring)."""

    enable_mem_pattern: bool = False
    enable_cpu_mem_arena: bool = True  # [engines] cpu_mem_arena (module docstring)
    intra_op_num_threads: int = 0
    deterministic: bool = True
    allow_spinning: bool = True
    """Whether the session's idle threads spin waiting for work (ONNX Runtime's default). Off for
    a short graph run between two runs of another session, so its threads leave the cores to the
    other session at once (e.g. a matcher's small product between two extractions)."""

    def build(self) -> ort.SessionOptions:
        options = ort.SessionOptions()
        options.enable_mem_pattern = self.enable_mem_pattern
        options.enable_cpu_mem_arena = self.enable_cpu_mem_arena
        options.intra_op_num_threads = self.intra_op_num_threads
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        options.use_deterministic_compute = self.deterministic
        options.log_severity_level = ORT_ERROR
        if not self.allow_spinning:
            options.add_session_config_entry("session.intra_op.allow_spinning", "0")
        return options


@dataclass(frozen=True, slots=True)
class _Loaded:
    path: Path
    manifest: EngineManifest
    session: ort.InferenceSession
    session_providers: tuple[str, ...]
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]


def _check_io(path: Path, role: str, declared: Sequence[TensorSpec], actual: Sequence[Any]) -> None:
    """Assert a session's real inputs/outputs equal the manifest's (names, dtypes, shapes)."""
    want = {t.name: t for t in declared}
    got = {a.name: a for a in actual}
    if set(want) != set(got):
        raise EngineError(
            path,
            f"graph {role} {sorted(got)} differ from the manifest's {sorted(want)}",
        )
    for name, spec in want.items():
        arg = got[name]
        dtype = _ORT_TO_NUMPY.get(arg.type, arg.type)
        if dtype != spec.dtype:
            raise EngineError(path, f"{role[:-1]} {name}: dtype {dtype} != manifest {spec.dtype}")
        shape = list(arg.shape)
        ok = len(shape) == len(spec.shape) and all(
            (isinstance(s, str) and not isinstance(g, int)) or (isinstance(s, int) and g == s)
            for s, g in zip(spec.shape, shape, strict=True)
        )
        if not ok:
            raise EngineError(
                path, f"{role[:-1]} {name}: shape {shape} != manifest {list(spec.shape)}"
            )


class OnnxInferenceRuntime:
    """Loads engines (checked against their manifests) and runs them; satisfies
    ``c3_matcher.protocols.InferenceRuntime``. Single-threaded use.

    ``providers_available`` injects the provider list (tests); ``None`` asks onnxruntime.
    """

    def __init__(
        self,
        providers_available: Sequence[str] | None = None,
        *,
        settings: SessionSettings | None = None,
        tensorrt_cache_dir: Path | None = None,
        requested: Sequence[str] | None = None,
        provider_settings: ProviderSettings | None = None,
    ) -> None:
        available = (
            list(ort.get_available_providers())
            if providers_available is None
            else list(providers_available)
        )
        self._providers = resolve_providers(requested, available)
        configured = configured_providers(requested)  # canonical names, as they are logged
        self._settings = settings or SessionSettings()
        self._tensorrt_cache_dir = tensorrt_cache_dir
        self._provider_settings = provider_settings or ProviderSettings()
        self._engines: dict[str, _Loaded] = {}
        self._selection = {
            "provider": self._providers[0],
            "chain": self._providers,
            "available": available,
            "requested": None if configured is None else list(configured),
            "not_installed": list(providers_not_installed(configured, available)),
            "onnxruntime": ort.__version__,
        }

    def log_selection(self) -> None:
        """Log the provider list (``c3.inference.provider_selected``, INFO) and, when configured
        providers are not installed, ``PROVIDER_NOT_INSTALLED`` (WARNING, forwarded to the FDR
        as warnings are): ``compose_root`` does once the log sinks are set up (the runtime is
        made before them)."""
        chain, origin = ", ".join(self._providers), self._selection["requested"]
        of = "the default chain, as installed" if origin is None else f"configured: {origin}"
        log_event(
            "INFO",
            "c3.inference.provider_selected",
            f"inference providers, preferred first: {chain} ({of})",
            **self._selection,
        )
        missing = self._selection["not_installed"]
        if missing:
            log_event(
                "WARNING",
                PROVIDER_NOT_INSTALLED,
                f"configured execution providers {missing} are not installed (onnxruntime "
                f"{ort.__version__} has {self._selection['available']}): the matcher runs on "
                f"{chain}; install an onnxruntime that has them, or leave them out of "
                f"{PROVIDERS_SETTING}",
                requested=origin,
                not_installed=missing,
                chain=self._providers,
                available=self._selection["available"],
            )

    @classmethod
    def from_settings(
        cls, engines: EngineSettings, providers_available: Sequence[str] | None = None
    ) -> OnnxInferenceRuntime:
        """A runtime from the ``[engines]`` settings (providers, per-provider options, threads).
        ONNX Runtime's own log is set to errors: its warnings are plain text on stderr, where
        the product writes JSON lines, and on a GPU it warns once per convolution and new input
        shape (2376 lines in one ``scripts/bench-gpu`` run, 2026-11-28); what matters of them is
        said by the matcher (``provider_fallback``, the determinism checks)."""
        ort.set_default_logger_severity(ORT_ERROR)
        return cls(
            providers_available,
            settings=SessionSettings(
                enable_cpu_mem_arena=engines.cpu_mem_arena,
                intra_op_num_threads=int(engines.intra_op_threads),
            ),
            tensorrt_cache_dir=engines.tensorrt_cache_dir,
            requested=engines.providers,
            provider_settings=ProviderSettings(
                device_id=engines.device_id,
                gpu_mem_limit_bytes=engines.gpu_mem_limit_bytes,
                tensorrt_fp16=engines.tensorrt_fp16,
                extra=engines.provider_options or None,
            ),
        )

    @property
    def provider(self) -> str:
        """The execution provider the loaded sessions ACTUALLY use (``get_providers()[0]``;
        several joined with ``+`` if they differ); before any engine is loaded, the requested
        one."""
        actual = list(dict.fromkeys(e.session_providers[0] for e in self._engines.values()))
        return "+".join(actual) if actual else self._providers[0]

    @property
    def requested_provider(self) -> str:
        """The preferred provider requested for the sessions (first of the provider list)."""
        return self._providers[0]

    @property
    def providers(self) -> tuple[str, ...]:
        """The requested session provider list, preferred first."""
        return tuple(self._providers)

    @property
    def session_providers(self) -> dict[str, tuple[str, ...]]:
        """Per loaded engine: the providers its session actually uses (``get_providers()``)."""
        return {k: e.session_providers for k, e in self._engines.items()}

    def load_engine(self, path: Any) -> str:
        """Check and load ``path``; return its engine id (the file stem, made unique). Idempotent
        per path.

        Raises ``EngineError`` (naming the file and the build command) when the file is missing,
        its name breaks the schema, its manifest is missing or disagrees, its sha256 differs, or
        the graph's real inputs/outputs differ from the manifest's. A symbolic link is not
        followed to find the manifest: it is the one beside ``path``, named as ``path`` is (an
        engine directory of links into a blob store).
        """
        engine_path = Path(path).expanduser().absolute()
        for engine_id, loaded in self._engines.items():
            if loaded.path == engine_path:
                return engine_id
        manifest = check_engine_file(engine_path, check_hash=True)
        start = time.perf_counter()
        session = self._open_session(engine_path, manifest)
        engine_id = engine_path.name.removesuffix(".onnx")
        if engine_id in self._engines:  # same file name in another directory
            engine_id = f"{engine_id}#{len(self._engines)}"
        loaded = _Loaded(
            engine_path,
            manifest,
            session,
            tuple(session.get_providers()),
            tuple(i.name for i in session.get_inputs()),
            tuple(o.name for o in session.get_outputs()),
        )
        self._engines[engine_id] = loaded
        self._log_loaded(engine_id, loaded, load_ms=(time.perf_counter() - start) * 1e3)
        return engine_id

    def _open_session(self, engine_path: Path, manifest: EngineManifest) -> ort.InferenceSession:
        """A session over the engine file with this runtime's options and providers, its real
        inputs and outputs checked against the manifest's."""
        try:
            session = ort.InferenceSession(
                str(engine_path),
                sess_options=self._settings.build(),
                providers=provider_options(
                    self._providers, self._tensorrt_cache_dir, self._provider_settings
                ),
            )
        except Exception as exc:  # onnxruntime raises its own exception types
            raise EngineError(engine_path, f"onnxruntime cannot load it ({exc})") from exc
        _check_io(engine_path, "inputs", manifest.inputs, session.get_inputs())
        _check_io(engine_path, "outputs", manifest.outputs, session.get_outputs())
        return session

    def _log_loaded(self, engine_id: str, loaded: _Loaded, *, load_ms: float) -> None:
        """``c3.inference.engine_loaded``, and ``c3.inference.provider_fallback`` (WARNING) when
        the session does not run on the requested provider."""
        actual = loaded.session_providers
        logger.bind(
            kind="c3.inference.engine_loaded",
            engine_id=engine_id,
            path=str(loaded.path),
            sha256=loaded.manifest.file_sha256,
            weights_sha256=loaded.manifest.weights_sha256,
            providers=list(actual),
            requested=list(self._providers),
            load_ms=round(load_ms, 1),
        ).info("engine {} loaded on {}", engine_id, actual[0] if actual else "?")
        if actual and actual[0] != self._providers[0]:
            logger.bind(
                kind="c3.inference.provider_fallback",
                engine_id=engine_id,
                requested=self._providers[0],
                actual=list(actual),
            ).warning(
                "engine {} runs on {}, not the requested {} (onnxruntime fell back)",
                engine_id,
                actual[0],
                self._providers[0],
            )

    def _get(self, engine_id: str) -> _Loaded:
        try:
            return self._engines[engine_id]
        except KeyError:
            raise KeyError(
                f"engine {engine_id!r} is not loaded (loaded: {sorted(self._engines)}); "
                "call load_engine(path) at start-up"
            ) from None

    def manifest(self, engine_id: str) -> EngineManifest:
        """The manifest of a loaded engine (weights sha256, I/O, verification figures...)."""
        return self._get(engine_id).manifest

    def engine_path(self, engine_id: str) -> Path:
        return self._get(engine_id).path

    def run(self, engine_id: str, feeds: Mapping[str, NDArray[Any]]) -> dict[str, NDArray[Any]]:
        """Run a loaded engine; ``feeds`` must name exactly the graph's inputs.

        Returns ``{output name: array}``. ``KeyError`` for an unknown engine id, ``ValueError``
        for wrong feed names; onnxruntime's own errors propagate (the caller maps them to
        ``MatcherBackboneError``).
        """
        loaded = self._get(engine_id)
        if set(feeds) != set(loaded.input_names):
            raise ValueError(
                f"engine {engine_id}: feeds {sorted(feeds)} != inputs {sorted(loaded.input_names)}"
            )
        values = loaded.session.run(list(loaded.output_names), {k: feeds[k] for k in feeds})
        return {name: np.asarray(v) for name, v in zip(loaded.output_names, values, strict=True)}
