"""Compare the engines of two directories graph by graph (same file names, i.e. same build keys).

    .venv/bin/python scripts/compare_engines.py NEW_DIR REFERENCE_DIR

For each ``*.onnx`` of NEW_DIR also in REFERENCE_DIR it prints whether the files are identical
and whether the ONNX graphs are, once the exporter's metadata is cleared: each node's source
stack trace (file and line of the export code) and the graph's printed range constraints (their
order varies from one export to the next). Equal graphs compute the same; exit code 1 when one
differs. Used to check that a change to the export code leaves the exported graphs as they were.
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

import onnx


def graph_bytes(path: Path) -> bytes:
    """The model's serialisation without the exporter's metadata."""
    model = onnx.load(str(path))
    for node in model.graph.node:
        del node.metadata_props[:]
    del model.graph.metadata_props[:]
    return model.SerializeToString(deterministic=True)


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print("usage: compare_engines.py NEW_DIR REFERENCE_DIR", file=sys.stderr)
        return 2
    new_dir, ref_dir = (Path(a) for a in argv)
    differ = 0
    for new in sorted(new_dir.glob("*.onnx")):
        ref = ref_dir / new.name
        if not ref.is_file():
            continue
        same_file = (
            hashlib.sha256(new.read_bytes()).digest() == hashlib.sha256(ref.read_bytes()).digest()
        )
        same_graph = graph_bytes(new) == graph_bytes(ref)
        differ += not same_graph
        print(
            f"{new.name}: file {'identical' if same_file else 'differs'}, "
            f"graph {'identical' if same_graph else 'DIFFERS'}"
        )
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
