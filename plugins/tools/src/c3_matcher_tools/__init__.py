"""c3-matcher ground tools: what the ground station runs and the flight computer never installs.

Engine building and verification (``engines build|bench``, extra ``engine-build`` with
PyTorch), tile-store building (``tiles``), simulated flights and datasets (``dataset``),
``replay``, ``eval``, ``bench``, plots and pictures, the SIFT + MAGSAC baseline and the
real-path test suite. Everything plugs into the core through its hooks (``plugin.py``), the way
a third party's plugin does.
"""
