"""DISK+LightGlue on real imagery through the real engines: the shared real-path suite
(rendered frames over three real orthophotos, the acceptance bar of issue 4)."""

from __future__ import annotations

from c3_matcher_tools.testing.realpath import RealPathSuite


class TestDiskLightGlueRealPath(RealPathSuite):
    strategy = "disk_lightglue"
