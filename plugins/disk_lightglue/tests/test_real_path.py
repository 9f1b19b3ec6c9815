"""DISK+LightGlue on real imagery through the real engines: the shared real-path suite
(rendered frames over three real orthophotos, the real-path acceptance bar)."""

from __future__ import annotations

from c3_matcher_tools.testing.realpath import RealPathSuite


class TestDiskLightGlueRealPath(RealPathSuite):
    strategy = "disk_lightglue"
