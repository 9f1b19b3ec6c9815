"""ALIKED+LightGlue on real imagery through the real engines: the shared real-path suite (the
SAME frames and bar as DISK+LightGlue), for the default n16 and the rotation-robust n16rot."""

from __future__ import annotations

from typing import ClassVar

from c3_matcher_tools.testing.realpath import RealPathSuite


class TestAlikedN16RealPath(RealPathSuite):
    strategy = "aliked_lightglue"


class TestAlikedN16RotRealPath(RealPathSuite):
    strategy = "aliked_lightglue"
    options: ClassVar[dict[str, object]] = {"variant": "n16rot"}
