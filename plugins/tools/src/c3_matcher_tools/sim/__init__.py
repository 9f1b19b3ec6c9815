"""Simulation over real orthophotos: nav-camera frames with exact ground truth, tiles,
distractors, photometric domain shift, and orthophoto loading (:mod:`.orthophotos`)."""

from __future__ import annotations

from c3_matcher_tools.sim.orthophotos import Orthophoto, load_orthophoto
from c3_matcher_tools.sim.photometric import PhotometricShift
from c3_matcher_tools.sim.render import (
    NavCameraRenderer,
    OrthoTile,
    RenderedFrame,
    cut_tile,
    ortho_to_undistorted_homography,
    pick_distractor_tiles,
    render_nav_frame,
)

__all__ = [
    "NavCameraRenderer",
    "OrthoTile",
    "Orthophoto",
    "PhotometricShift",
    "RenderedFrame",
    "cut_tile",
    "load_orthophoto",
    "ortho_to_undistorted_homography",
    "pick_distractor_tiles",
    "render_nav_frame",
]
