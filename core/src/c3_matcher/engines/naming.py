"""The self-describing engine file name schema.

``{model}_{variant}_{precision}_{input_rule}_op{opset}_{hash}.onnx``, e.g.
``disk_depth_fp32_hw16-k2048_op18_3f9a1c2b7d.onnx``; every token matches ``[a-z0-9-]+`` and
``hash`` is the first 10 hex digits of the build key (weights sha256, export parameters, exporter
and library versions). The manifest lies beside it: ``<stem>.manifest.json``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

__all__ = ["ENGINE_SUFFIX", "MANIFEST_SUFFIX", "EngineName", "manifest_path_for"]

ENGINE_SUFFIX = ".onnx"
MANIFEST_SUFFIX = ".manifest.json"
_HASH_LEN = 10
_PATTERN = re.compile(
    r"^(?P<model>[a-z0-9][a-z0-9-]*)_(?P<variant>[a-z0-9][a-z0-9-]*)_"
    r"(?P<precision>[a-z0-9][a-z0-9-]*)_(?P<input_rule>[a-z0-9][a-z0-9-]*)_"
    r"op(?P<opset>[0-9]+)_(?P<hash>[0-9a-f]{10})\.onnx$"
)


@dataclass(frozen=True, slots=True)
class EngineName:
    """The parsed parts of an engine file name."""

    model: str
    variant: str
    precision: str
    input_rule: str
    opset: int
    short_hash: str

    @property
    def filename(self) -> str:
        return (
            f"{self.model}_{self.variant}_{self.precision}_{self.input_rule}_"
            f"op{self.opset}_{self.short_hash}{ENGINE_SUFFIX}"
        )

    @property
    def stem(self) -> str:
        return self.filename[: -len(ENGINE_SUFFIX)]

    @property
    def manifest_filename(self) -> str:
        return self.stem + MANIFEST_SUFFIX

    @classmethod
    def from_build_key(
        cls, model: str, variant: str, precision: str, input_rule: str, opset: int, build_key: str
    ) -> EngineName:
        """The name of an engine whose build key (hex sha256) is ``build_key``."""
        name = cls(model, variant, precision, input_rule, opset, build_key[:_HASH_LEN])
        cls.parse(name.filename)  # validates every token
        return name

    @classmethod
    def parse(cls, filename: str) -> EngineName:
        """Parse a file name; ``ValueError`` says what the schema expects."""
        match = _PATTERN.match(filename)
        if match is None:
            raise ValueError(
                f"{filename!r} does not follow the engine name schema "
                "{model}_{variant}_{precision}_{input_rule}_op{opset}_{hash10}.onnx"
            )
        return cls(
            match["model"],
            match["variant"],
            match["precision"],
            match["input_rule"],
            int(match["opset"]),
            match["hash"],
        )

    @staticmethod
    def glob_for(model: str, variant: str) -> str:
        """The glob pattern of every engine file of ``model``/``variant``."""
        return f"{model}_{variant}_*_*_op*_*{ENGINE_SUFFIX}"


def manifest_path_for(engine_path: Path) -> Path:
    """The manifest file that belongs to ``engine_path``."""
    name = engine_path.name
    stem = name[: -len(ENGINE_SUFFIX)] if name.endswith(ENGINE_SUFFIX) else engine_path.stem
    return engine_path.with_name(stem + MANIFEST_SUFFIX)
