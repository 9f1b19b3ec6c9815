"""``[matcher.options.xfeat]``: the XFeat strategy's options (validated by ``compose_root``).

    [matcher.options.xfeat]
    matcher = "mnn"          # "mnn" (numpy mutual nearest neighbour) or "lighterglue"
    min_cossim = 0.82        # mnn only: minimum cosine similarity of a kept match
    max_keypoints = 4096     # keypoint budget per image (default: see below)
    upscale = 1              # run XFeat on each prepared image enlarged this many times (1..4)

Unknown keys and bad values are refused, naming the field (``extra="forbid"``); so is
``min_cossim`` given with ``matcher = "lighterglue"``, which does not read it.

``upscale``: XFeat samples its descriptors from a map of 1/8 the input's resolution, so a small
image leaves it too few cells to tell places apart: a candidate window of 256 px (a tile store's
own tile size) gives a 32 x 32 map, a 160 px one 20 x 20, against the 80 x 60 of the VGA images
XFeat is made for. Enlarging every image twice before the extractor gives such windows a map
near that size; the price is four times the extractor's work. Keypoints come back in the
prepared image's px: nothing after the extractor changes. Measured on every shipped flight
(docs/precision.md): 2 finds the true tile on 51 of 203 frames against 23 with 1, no flight
loses one, none of either gives a confident wrong fix; but a frame served stored map features
takes p95 145 ms against 73, past XFeat's goal of 100 ms, so the default stays 1: set 2 (or 3
for windows under 200 px) where recall matters more than time. Map features built with a
factor are keyed by it: they serve flights of that factor only.

Keypoint budget, when ``max_keypoints`` is not given here: ``[matcher] max_keypoints`` if that is
set explicitly (above the engine's top-K the extractor keeps the top-K, and says so once at
start-up: ``c3.matcher.keypoints_capped``, as for every strategy), else
``DEFAULT_MAX_KEYPOINTS[matcher]``: 4096 for mnn (upstream XFeat's
``top_k``; measured on the real-path scenarios, the 2048 of ``[matcher]``'s LightGlue convention
leaves the Manila yaw-120 frame at 35 inliers with mnn, 4096 gives 101), 2048 for lighterglue
(passes every scenario; attention cost grows with the square of the count).
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator

from c3_matcher.prepared import MAX_UPSCALE
from c3_matcher_xfeat.engines import XFEAT_TOP_K

__all__ = [
    "DEFAULT_MAX_KEYPOINTS",
    "DEFAULT_MIN_COSSIM",
    "DEFAULT_UPSCALE",
    "XFEAT_MAX_KEYPOINTS",
    "XFeatMatcherKind",
    "XFeatOptions",
]

XFeatMatcherKind = Literal["mnn", "lighterglue"]
DEFAULT_MIN_COSSIM = 0.82
"""Upstream ``XFeat.match``'s default: a mutual nearest neighbour must also exceed it."""
XFEAT_MAX_KEYPOINTS = XFEAT_TOP_K
"""The engine's fixed top-K: no budget can exceed it."""
DEFAULT_UPSCALE = 1
"""The extractor sees each prepared image as it is (module docstring: ``upscale``)."""
DEFAULT_MAX_KEYPOINTS: dict[str, int] = {"mnn": 4096, "lighterglue": 2048}
"""Per-matcher keypoint budget when neither this table nor ``[matcher]`` sets one."""


class XFeatOptions(BaseModel):
    """How XFeat features are matched: ``matcher`` picks the mutual nearest neighbour (numpy,
    deterministic) or LighterGlue (an ONNX engine in the shared LightGlue runtime);
    ``min_cossim`` is the mnn matcher's minimum cosine similarity (<= 0: no minimum, as
    upstream); ``max_keypoints`` the per-image keypoint budget (None: see the module doc);
    ``upscale`` how many times each image is enlarged before the extractor."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    matcher: XFeatMatcherKind = Field("mnn", description="mnn (default) or lighterglue")
    min_cossim: float = Field(
        DEFAULT_MIN_COSSIM, ge=-1.0, lt=1.0, description="mnn: minimum cosine similarity"
    )
    max_keypoints: int | None = Field(
        None, ge=16, le=XFEAT_MAX_KEYPOINTS, description="keypoints per image (None: default)"
    )
    upscale: int = Field(
        DEFAULT_UPSCALE,
        ge=1,
        le=MAX_UPSCALE,
        description="the extractor runs on each image enlarged this many times",
    )

    @field_validator("min_cossim", "max_keypoints", "upscale", mode="before")
    @classmethod
    def _no_boolean(cls, value: object) -> object:
        """A boolean is no number (``upscale = true`` must not mean 1, nor ``min_cossim = false``
        0): refused. Other values are read as pydantic reads numbers, so that a whole number
        given as text, as every environment variable is (``..._XFEAT__UPSCALE=3``), is taken and
        a fraction (2.5) is refused."""
        if isinstance(value, bool):
            raise ValueError(f"expected a number, got the boolean {str(value).lower()}")
        return value

    @field_validator("min_cossim")
    @classmethod
    def _only_for_mnn(cls, value: float, info: ValidationInfo) -> float:
        """A ``min_cossim`` given with another matcher would be silently ignored: refused."""
        matcher = info.data.get("matcher")
        if matcher is not None and matcher != "mnn":
            raise ValueError(
                f"min_cossim is the mnn matcher's threshold; matcher = {matcher!r} does not "
                'read it (remove min_cossim, or set matcher = "mnn")'
            )
        return value

    def keypoint_budget(self, matcher_max_keypoints: int | None) -> int:
        """The effective budget: this table's, else ``matcher_max_keypoints`` (``[matcher]``'s,
        only when set explicitly), else the matcher's default. A ``[matcher]`` budget above the
        engine's top-K is kept here: the extractor backend caps it and says so."""
        if self.max_keypoints is not None:
            return self.max_keypoints
        if matcher_max_keypoints is not None:
            return matcher_max_keypoints
        return DEFAULT_MAX_KEYPOINTS[self.matcher]

    def matches_with_lightglue(self) -> bool:
        """LighterGlue runs in the shared LightGlue runtime (``[lightglue]`` applies); mnn
        does not."""
        return self.matcher == "lighterglue"
