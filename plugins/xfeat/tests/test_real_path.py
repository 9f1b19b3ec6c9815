"""XFeat on real imagery through the real engines: the shared real-path suite (the SAME frames
and bar as DISK+LightGlue), for both matcher options."""

from __future__ import annotations

from typing import ClassVar

from c3_matcher_tools.testing.realpath import RealPathSuite


class TestXFeatMnnRealPath(RealPathSuite):
    strategy = "xfeat"
    options: ClassVar[dict[str, object]] = {"matcher": "mnn"}


class TestXFeatLighterGlueRealPath(RealPathSuite):
    strategy = "xfeat"
    options: ClassVar[dict[str, object]] = {"matcher": "lighterglue"}
